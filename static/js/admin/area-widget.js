/* The operation-area widget of the vehicle admin (fleet/widgets.py): the area's polygon on a
   Leaflet map, drawn and edited with Leaflet-Geoman and written back into the textarea as a
   closed ring of [lat, lng] (the last point repeats the first), which is what the form saves.
   The textarea is only rewritten when the operator changes the polygon on the map, so a form
   saved without touching the map leaves the area as it was.

   State for tests, on the map's element: data-state ("ready" once drawn), data-points (the
   polygon's distinct vertices, 0 for none), data-valid (whether the textarea holds a ring the
   map can draw); window.CPCCAreaWidgets holds each widget's {map, polygon()} by input id. */
(function () {
  'use strict';

  var M = window.CPCCAdminMap;
  var AREA_STYLE = { color: '#c0392b', weight: 3, fillColor: '#c0392b', fillOpacity: 0.15 };
  var DIGITS = 1e6; // about 0.1 m

  function round(x) {
    return Math.round(x * DIGITS) / DIGITS;
  }

  /* The points of a JSON ring, or null when the text is not one. */
  function parseRing(text) {
    var value;
    try {
      value = JSON.parse(text);
    } catch (e) {
      return null;
    }
    if (!Array.isArray(value) || value.length < 3) return null;
    for (var i = 0; i < value.length; i++) {
      var p = value[i];
      if (!Array.isArray(p) || p.length !== 2 || !isFinite(p[0]) || !isFinite(p[1]) ||
          typeof p[0] !== 'number' || typeof p[1] !== 'number') return null;
    }
    return M.openRing(value);
  }

  /* The polygon's outer ring as the model stores it: closed, rounded. */
  function ringOf(layer) {
    var latlngs = layer.getLatLngs();
    while (latlngs.length && Array.isArray(latlngs[0])) latlngs = latlngs[0];
    var ring = latlngs.map(function (ll) { return [round(ll.lat), round(ll.lng)]; });
    if (ring.length) ring.push(ring[0].slice());
    return ring;
  }

  function numberOf(id) {
    var input = document.getElementById(id);
    var value = input ? parseFloat(input.value) : NaN;
    return isFinite(value) ? value : null;
  }

  function init(element) {
    var input = document.getElementById(element.dataset.input);
    var context = JSON.parse(document.getElementById(element.dataset.context).textContent);
    var map = M.createMap(element, element.dataset.tiles);
    var others = M.addAreas(map, context.others, { dashArray: '6 4' });
    var stations = M.addStations(map, context.stations, false);
    var polygon = null;

    var depot = L.circleMarker([0, 0], {
      radius: 5, color: '#222222', weight: 2, fillColor: '#ffffff', fillOpacity: 1,
      pmIgnore: true, snapIgnore: true
    }).bindTooltip(M.text('depot'));
    function placeDepot() {
      var lat = numberOf('id_depot_lat');
      var lng = numberOf('id_depot_lng');
      if (lat === null || lng === null) {
        map.removeLayer(depot);
      } else {
        depot.setLatLng([lat, lng]).addTo(map);
      }
    }
    ['id_depot_lat', 'id_depot_lng'].forEach(function (id) {
      var field = document.getElementById(id);
      if (field) field.addEventListener('input', placeDepot);
    });

    function report() {
      element.dataset.points = polygon ? String(ringOf(polygon).length - 1) : '0';
      element.dataset.valid = String(parseRing(input.value) !== null);
    }

    function write() {
      input.value = polygon ? JSON.stringify(ringOf(polygon)) : '';
      report();
    }

    function adopt(layer) {
      polygon = layer;
      polygon.setStyle(AREA_STYLE);
      polygon.on('pm:edit pm:dragend', write);
    }

    function show(points) {
      if (polygon) map.removeLayer(polygon);
      polygon = null;
      if (points) adopt(L.polygon(points).addTo(map));
    }

    map.pm.setGlobalOptions({ snappable: true, snapDistance: 15, allowSelfIntersection: false });
    map.pm.addControls({
      position: 'topleft',
      drawMarker: false,
      drawCircleMarker: false,
      drawPolyline: false,
      drawCircle: false,
      drawText: false,
      drawRectangle: true,
      drawPolygon: true,
      editMode: true,
      dragMode: true,
      cutPolygon: false,
      rotateMode: false,
      removalMode: true
    });
    map.on('pm:create', function (e) {
      // An RV has one area: a new drawing replaces the old one.
      if (polygon) map.removeLayer(polygon);
      adopt(e.layer);
      write();
    });
    map.on('pm:remove', function (e) {
      if (e.layer === polygon) {
        polygon = null;
        write();
      }
    });
    input.addEventListener('input', function () {
      // A ring typed or pasted into the textarea is drawn as soon as it is one.
      var points = parseRing(input.value);
      if (points) show(points);
      report();
    });

    show(parseRing(input.value));
    placeDepot();
    if (polygon) map.fitBounds(polygon.getBounds(), { padding: [24, 24], maxZoom: 18 });
    else M.fit(map, [others, stations]);
    report();
    element.dataset.state = 'ready';
    window.CPCCAreaWidgets = window.CPCCAreaWidgets || {};
    window.CPCCAreaWidgets[input.id] = { map: map, polygon: function () { return polygon; } };
  }

  document.addEventListener('DOMContentLoaded', function () {
    document.querySelectorAll('[data-area-map]').forEach(init);
  });
})();
