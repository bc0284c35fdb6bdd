/* A flight's page in the admin (fleet/admin.py, FlightAdmin.flight_view): where it flew on a
   map, a replay along its track (the slider and Play), and its altitude and battery over the
   flight (Chart.js, served by the platform). Its data is the page's JSON "flight-data":
   {track: [[t_s, lat, lng, alt, battery_pct or null], ...], started_s, tiles, depot: [lat, lng]}. */
(function () {
  'use strict';

  function minutesLabel(seconds) {
    var s = Math.round(seconds);
    var m = Math.floor(s / 60);
    return m + ':' + String(s % 60).padStart(2, '0');
  }

  /* The position at ``t`` on the track (linear between its points). */
  function at(track, t) {
    if (t <= track[0][0]) return track[0];
    for (var i = 1; i < track.length; i++) {
      var b = track[i];
      if (t <= b[0]) {
        var a = track[i - 1];
        var f = b[0] > a[0] ? (t - a[0]) / (b[0] - a[0]) : 1;
        return [t, a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f, a[3] + (b[3] - a[3]) * f];
      }
    }
    return track[track.length - 1];
  }

  function drawMap(element, data) {
    var text = window.CPCCAdminMap.text;
    var map = window.CPCCAdminMap.createMap(element, data.tiles, {});
    var points = data.track.map(function (p) { return [p[1], p[2]]; });
    var line = L.polyline(points, { color: '#1f77b4', weight: 3 }).addTo(map);
    L.circleMarker(points[0], { radius: 6, color: '#2e7d32', fillOpacity: 1 })
      .bindTooltip(text('take-off')).addTo(map);
    L.circleMarker(points[points.length - 1], { radius: 6, color: '#c62828', fillOpacity: 1 })
      .bindTooltip(text('landing')).addTo(map);
    map.fitBounds(line.getBounds(), { padding: [24, 24], maxZoom: 18 });
    element.dataset.state = 'ready';
    element.dataset.points = String(points.length);
    return map;
  }

  function replay(map, data, controls) {
    var track = data.track;
    var t0 = track[0][0];
    var t1 = track[track.length - 1][0];
    var marker = L.circleMarker([track[0][1], track[0][2]], {
      radius: 8, color: '#111', weight: 2, fillColor: '#ffca28', fillOpacity: 1
    }).addTo(map);
    var slider = controls.querySelector('input[type=range]');
    var label = controls.querySelector('[data-replay-time]');
    var button = controls.querySelector('button');
    var timer = null;
    slider.min = '0';
    slider.max = String(Math.max(t1 - t0, 0));
    slider.step = 'any';
    slider.value = '0';

    function show(offset) {
      var p = at(track, t0 + offset);
      marker.setLatLng([p[1], p[2]]);
      label.textContent = minutesLabel(offset) + ' · ' + p[3].toFixed(1) + ' m';
    }

    function stop() {
      if (timer !== null) clearInterval(timer);
      timer = null;
      button.textContent = 'Play';
    }

    slider.addEventListener('input', function () { show(Number(slider.value)); });
    button.addEventListener('click', function () {
      if (timer !== null) { stop(); return; }
      if (Number(slider.value) >= Number(slider.max)) slider.value = '0';
      button.textContent = 'Pause';
      // The whole flight in about 10 s, whatever its length.
      var step = Math.max((t1 - t0) / 100, 0.1);
      timer = setInterval(function () {
        var next = Math.min(Number(slider.value) + step, Number(slider.max));
        slider.value = String(next);
        show(next);
        if (next >= Number(slider.max)) stop();
      }, 100);
    });
    show(0);
    controls.hidden = false;
  }

  function chart(canvas, data, index, label, unit) {
    var t0 = data.track[0][0];
    var values = data.track
      .filter(function (p) { return p[index] !== null && p[index] !== undefined; })
      .map(function (p) { return { x: p[0] - t0, y: p[index] }; });
    if (!values.length) {
      canvas.parentNode.hidden = true;
      return;
    }
    new window.Chart(canvas, {
      type: 'line',
      data: { datasets: [{ label: label, data: values, borderColor: '#1f77b4', pointRadius: 0 }] },
      options: {
        animation: false,
        parsing: false,
        plugins: { legend: { display: false } },
        scales: {
          x: { type: 'linear', title: { display: true, text: 'minutes after take-off' },
               ticks: { callback: function (v) { return minutesLabel(v); } } },
          y: { title: { display: true, text: unit } }
        }
      }
    });
    canvas.dataset.points = String(values.length);
  }

  document.addEventListener('DOMContentLoaded', function () {
    var source = document.getElementById('flight-data');
    var element = document.getElementById('flight-map');
    if (!source || !element) return;
    var data = JSON.parse(source.textContent);
    if (!data.track || data.track.length < 2) {
      element.dataset.state = 'empty';
      return;
    }
    var map = drawMap(element, data);
    replay(map, data, document.getElementById('flight-replay'));
    if (window.Chart) {
      chart(document.getElementById('flight-altitude'), data, 3, 'altitude', 'm above home');
      chart(document.getElementById('flight-battery'), data, 4, 'battery', '%');
    }
  });
})();
