/* A VV's page (templates/missions/vv_detail.html): its mission on a small map, live from the
 * map's socket (/ws/map/?vv=<id>) while it has not ended, and replayed from its history
 * (/vvs/<id>/map.json) with a time slider once it has; and the chart of its scalar readings
 * (Chart.js), one series per sensor, one chart per unit, against the time of the readings
 * (UTC clock times; a 'linear' axis of seconds, so no date adapter is needed).
 *
 * State for whoever looks (tests): window.cpccMap (static/js/map.js) and, on #vv-map,
 * data-replay-from / data-replay-to (seconds on the platform clock) once a replay is ready;
 * on #vv-charts, data-time-origin: the epoch milliseconds of the charts' x = 0 (each point
 * also keeps its reading's time as t, epoch milliseconds); on #vv-waiting, data-reason: what
 * the VV waits for (the API's waiting.reason, '' when nothing). */
(function () {
  'use strict';

  var LABELS = {
    queued: 'Queued', running: 'Running', migrating: 'Migrating', finished: 'Finished',
    failed: 'Failed', killed: 'Killed', cancelled: 'Cancelled'
  };
  var ENDED = { finished: true, failed: true, killed: true, cancelled: true };
  var PALETTE = ['#1f6fe5', '#d62828', '#2a9d3a', '#e17055', '#6c5ce7', '#00838f', '#b7791f', '#5d6878'];
  var PLAY_MS = 20000;

  function clock(seconds) {
    seconds = Math.max(0, Math.round(seconds));
    var h = Math.floor(seconds / 3600), m = Math.floor((seconds % 3600) / 60), s = seconds % 60;
    return (h ? h + ':' : '') + String(m).padStart(2, '0') + ':' + String(s).padStart(2, '0');
  }

  function live(el, map) {
    var id = el.dataset.vv;
    var badge = document.getElementById('vv-status');
    var where = document.getElementById('vv-where');
    var status = document.getElementById('vv-map-status');
    var shown = badge ? badge.className.replace(/.*status-(\w+).*/, '$1') : '';
    map.options.onDraw = function () {
      status.textContent = (el.dataset.connected === 'true' ? 'live' : 'reconnecting…') + ' · ' +
        el.dataset.tasksOpen + ' open, ' + el.dataset.tasksDone + ' done';
      var vv = map.vvs[id];
      if (!vv || !vv.status || vv.status === shown) return;
      shown = vv.status;
      badge.className = 'badge status-' + vv.status;
      badge.textContent = LABELS[vv.status] || vv.status;
      if (where) {
        if (vv.host) where.textContent = vv.host + (vv.host_kind === 'rv' ? ' (vehicle)' : ' (ground station)');
        else if (vv.host_kind === 'rv') where.textContent = 'in flight';
        else if (vv.host_kind === 'gs') where.textContent = 'at a ground station';
      }
      if (ENDED[vv.status]) {
        document.getElementById('vv-ended-note').hidden = false;
        // Nothing to cancel or edit any more.
        document.querySelectorAll('.head-actions form[action$="/cancel/"], .head-actions a[href$="/edit/"]')
          .forEach(function (action) { action.hidden = true; });
      }
    };
    map.connect(el.dataset.socket);
  }

  // What the VV waits for (#vv-waiting, while it has not ended): read again from the API
  // (GET /api/v1/vvs/<id>/, its `waiting`) every WAITING_POLL_MS until the VV ends.
  var WAITING_POLL_MS = 5000;

  function waiting() {
    var box = document.getElementById('vv-waiting');
    if (!box || !box.dataset.api) return;
    var label = document.getElementById('vv-waiting-label');
    var message = document.getElementById('vv-waiting-message');
    function show(vv) {
      var w = vv.waiting;
      box.hidden = !w;
      box.dataset.reason = w ? w.reason : '';
      if (!w) return;
      label.textContent = (w.reason === 'flying' ? 'On its way' : 'Waiting') + ':';
      message.textContent = w.message;
    }
    function look() {
      fetch(box.dataset.api, { credentials: 'same-origin', headers: { Accept: 'application/json' } })
        .then(function (response) {
          if (!response.ok) throw new Error(String(response.status));
          return response.json();
        })
        .then(function (vv) {
          show(vv);
          if (!ENDED[vv.status]) setTimeout(look, WAITING_POLL_MS);
        })
        .catch(function () { setTimeout(look, WAITING_POLL_MS * 3); });
    }
    setTimeout(look, WAITING_POLL_MS);
  }

  function replay(el, map) {
    var status = document.getElementById('vv-map-status');
    var box = document.getElementById('replay');
    var slider = document.getElementById('replay-time');
    var output = document.getElementById('replay-clock');
    var play = document.getElementById('replay-play');
    var start = Number(el.dataset.start || 0);
    fetch(el.dataset.history, { credentials: 'same-origin' })
      .then(function (response) {
        if (!response.ok) throw new Error(String(response.status));
        return response.json();
      })
      .then(function (snapshot) {
        map.applySnapshot(snapshot);
        var times = [];
        (snapshot.vvs || []).forEach(function (vv) {
          vv.tasks.forEach(function (t) {
            if (t.requested_s !== null) times.push(t.requested_s);
            if (t.done_s !== null) times.push(t.done_s);
          });
          vv.track.forEach(function (p) { times.push(p[0]); });
          vv.migrations.forEach(function (m) { times.push(m.at_s); });
        });
        if (!times.length) {
          status.textContent = 'no flight to replay';
          return;
        }
        var from = Math.min.apply(null, times), to = Math.max.apply(null, times);
        el.dataset.replayFrom = String(from);
        el.dataset.replayTo = String(to);
        var span = Math.max(to - from, 1e-6);
        function at(value) { return from + span * value / 1000; }
        function set(value) {
          slider.value = String(value);
          var t = at(value);
          map.setTime(t);
          output.textContent = clock(t - start) + ' / ' + clock(to - start);
        }
        var timer = null;
        function stop() {
          if (timer !== null) cancelAnimationFrame(timer);
          timer = null;
          play.textContent = '▶ Play';
        }
        play.addEventListener('click', function () {
          if (timer !== null) { stop(); return; }
          var begun = performance.now();
          var value0 = Number(slider.value) >= 1000 ? 0 : Number(slider.value);
          play.textContent = '❚❚ Pause';
          var step = function (now) {
            var value = Math.min(1000, value0 + (now - begun) / PLAY_MS * 1000);
            set(value);
            if (value >= 1000) { stop(); return; }
            timer = requestAnimationFrame(step);
          };
          timer = requestAnimationFrame(step);
        });
        slider.addEventListener('input', function () { stop(); set(Number(slider.value)); });
        box.hidden = false;
        status.textContent = 'replay of its mission';
        set(1000);
      })
      .catch(function (error) { status.textContent = 'its mission could not be loaded (' + error.message + ')'; });
  }

  // Tick spacings of the time axis, in seconds: steps a clock shows.
  var CLOCK_STEPS = [1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 10800,
    21600, 43200, 86400];
  var DAY_MS = 86400000;

  // A moment (epoch milliseconds) as a UTC clock time, "13:04:05", with its date in front
  // ("2026-11-27 13:04:05") when asked.
  function utcClock(ms, withDate) {
    var iso = new Date(ms).toISOString();
    return (withDate ? iso.slice(0, 10) + ' ' : '') + iso.slice(11, 19);
  }

  // The smallest clock step that puts at most about 8 ticks on a span of seconds.
  function clockStep(spanS) {
    for (var i = 0; i < CLOCK_STEPS.length; i++) {
      if (spanS / CLOCK_STEPS[i] <= 8) return CLOCK_STEPS[i];
    }
    return Math.ceil(spanS / 8 / 86400) * 86400;
  }

  function charts() {
    var data = document.getElementById('chart-data');
    var holder = document.getElementById('vv-charts');
    if (!data || !holder || !window.Chart) return;
    var series = JSON.parse(data.textContent);
    // x is seconds since midnight (UTC) of the first reading's day: ticks at multiples of a
    // clock step fall on round clock times.
    var first = Infinity, last = -Infinity;
    series.forEach(function (s) {
      s.points.forEach(function (p) { first = Math.min(first, p[0]); last = Math.max(last, p[0]); });
    });
    if (first === Infinity) return;
    var origin = Math.floor(first / DAY_MS) * DAY_MS;
    var spansDays = last - origin >= DAY_MS;
    var step = clockStep(Math.max(1, (last - first) / 1000));
    holder.dataset.timeOrigin = String(origin);
    var byUnit = {};
    var units = [];
    series.forEach(function (s) {
      if (!byUnit[s.unit]) { byUnit[s.unit] = []; units.push(s.unit); }
      byUnit[s.unit].push(s);
    });
    var colour = 0;
    units.forEach(function (unit) {
      var box = document.createElement('div');
      box.className = 'chart-box';
      var title = document.createElement('h3');
      title.textContent = byUnit[unit].map(function (s) { return s.sensor; }).join(', ') + (unit ? ' (' + unit + ')' : '');
      var wrap = document.createElement('div');
      wrap.className = 'canvas';
      var canvas = document.createElement('canvas');
      canvas.setAttribute('role', 'img');
      canvas.setAttribute('aria-label', 'Chart of ' + title.textContent + ' over time (UTC)');
      wrap.appendChild(canvas);
      box.appendChild(title);
      box.appendChild(wrap);
      holder.appendChild(box);
      new window.Chart(canvas, {
        type: 'line',
        data: {
          datasets: byUnit[unit].map(function (s) {
            var c = PALETTE[colour++ % PALETTE.length];
            return {
              label: s.sensor, borderColor: c, backgroundColor: c, borderWidth: 2, pointRadius: 3,
              tension: 0, spanGaps: true,
              data: s.points.map(function (p) {
                return { x: (p[0] - origin) / 1000, y: p[1], t: p[0], task: p[2] };
              })
            };
          })
        },
        options: {
          animation: false, responsive: true, maintainAspectRatio: false,
          interaction: { mode: 'nearest', intersect: false },
          scales: {
            x: {
              type: 'linear',
              title: { display: true, text: 'time (UTC)' },
              ticks: {
                stepSize: step,
                maxRotation: 0,
                callback: function (value) { return utcClock(origin + value * 1000, spansDays); }
              }
            },
            y: { title: { display: !!unit, text: unit } }
          },
          plugins: {
            legend: { display: byUnit[unit].length > 1, position: 'bottom' },
            tooltip: {
              callbacks: {
                title: function (items) {
                  return utcClock(items[0].raw.t, true) + ' UTC · task ' + items[0].raw.task;
                },
                label: function (item) { return item.dataset.label + ': ' + item.parsed.y + (unit ? ' ' + unit : ''); }
              }
            }
          }
        }
      });
    });
  }

  document.addEventListener('DOMContentLoaded', function () {
    waiting();
    charts();
    var el = document.getElementById('vv-map');
    if (!el || !window.CPCCMap) return;
    var map = new window.CPCCMap(el, { tiles: el.dataset.tiles || '' });
    window.cpccMap = map;
    if (el.dataset.mode === 'replay') replay(el, map);
    else live(el, map);
  });
})();
