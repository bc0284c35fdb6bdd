/* What the admin's maps share (the area widget, the fleet overview): a Leaflet map on the
   tiles of the CPCC_MAP_TILES setting, or else on the platform's own tiles of the simulated
   world (/tiles/{z}/{x}/{y}.png, fleet/views.py); the RVs' operation areas and the ground
   stations. Nothing is loaded from outside the platform unless tiles are configured. */
(function () {
  'use strict';

  var STATUS_COLORS = { active: '#1f77b4', maintenance: '#e08a00', removed: '#8a8a8a' };
  var STATION_COLOR = '#7b3fa0';
  var PLATFORM_TILES = '/tiles/{z}/{x}/{y}.png';

  /* Tooltip and popup content from text: names are typed by operators, never HTML. */
  function text(value) {
    var span = document.createElement('span');
    span.textContent = value;
    return span;
  }

  function statusColor(status) {
    return STATUS_COLORS[status] || STATUS_COLORS.removed;
  }

  /* Where the pointer is: the simulated world's tiles show no names to read a position by. */
  var Coordinates = L.Control.extend({
    options: { position: 'bottomleft' },
    onAdd: function (map) {
      var box = L.DomUtil.create('div', 'cpcc-map-coordinates');
      box.textContent = '';
      map.on('mousemove', function (e) {
        box.textContent = e.latlng.lat.toFixed(5) + ', ' + e.latlng.lng.toFixed(5);
      });
      map.on('mouseout', function () {
        box.textContent = '';
      });
      return box;
    }
  });

  function tileHost(template) {
    try {
      return new URL(template.replace(/\{[^}]*\}/g, 'a')).host;
    } catch (e) {
      return template;
    }
  }

  /* options: Leaflet map options (e.g. preferCanvas). */
  function createMap(element, tiles, options) {
    var map = L.map(element, L.extend({ zoomSnap: 0.5, maxZoom: 21, attributionControl: false },
      options || {}));
    L.control.attribution({ prefix: false }).addTo(map);
    var layer = tiles
      ? L.tileLayer(tiles, { maxZoom: 21, maxNativeZoom: 19, attribution: 'Tiles: ' + tileHost(tiles) })
      : L.tileLayer(PLATFORM_TILES, { maxZoom: 21, maxNativeZoom: 19, attribution: 'Background: the simulated world' });
    element.classList.add('cpcc-map-plain'); // under the tiles while they load
    element.dataset.tilesLoaded = '0';
    layer.on('tileload', function () {
      element.dataset.tilesLoaded = String(Number(element.dataset.tilesLoaded) + 1);
    });
    // On the map once the page's script has fitted it to what it shows: tiles of the world
    // view set below would be asked for, then dropped half-loaded.
    setTimeout(function () { layer.addTo(map); }, 0);
    // A view before any layer: Leaflet's SVG renderer fails on paths added to a map without one.
    map.setView([20, 0], 2);
    L.control.scale({ imperial: false }).addTo(map);
    new Coordinates().addTo(map);
    return map;
  }

  /* A closed ring of [lat, lng] as Leaflet wants it: the repeated last point dropped. */
  function openRing(ring) {
    var points = ring.map(function (p) { return [Number(p[0]), Number(p[1])]; });
    var first = points[0];
    var last = points[points.length - 1];
    if (points.length > 3 && first[0] === last[0] && first[1] === last[1]) points.pop();
    return points;
  }

  /* vehicles: [{name, status, area}]; drawn for orientation, never edited. */
  function addAreas(map, vehicles, style) {
    var group = L.featureGroup();
    vehicles.forEach(function (v) {
      if (!v.area || v.area.length < 3) return;
      var color = statusColor(v.status);
      L.polygon(openRing(v.area), L.extend({
        color: color, weight: 1.5, opacity: 0.8, fillColor: color, fillOpacity: 0.07,
        pmIgnore: true
      }, style || {})).bindTooltip(text(v.name + ' (' + v.status + ')'), { sticky: true }).addTo(group);
    });
    return group.addTo(map);
  }

  /* stations: [{name, lat, lng}]. */
  function addStations(map, stations, labels) {
    var group = L.featureGroup();
    stations.forEach(function (gs) {
      var marker = L.circleMarker([gs.lat, gs.lng], {
        radius: 6, color: '#ffffff', weight: 2, fillColor: STATION_COLOR, fillOpacity: 1,
        pmIgnore: true, snapIgnore: true
      });
      marker.bindTooltip(text(gs.name), labels
        ? { permanent: true, direction: 'right', offset: [8, 0], className: 'cpcc-map-label' }
        : {});
      marker.addTo(group);
    });
    return group.addTo(map);
  }

  /* Fit the map to what it shows, or show the whole world when it shows nothing. */
  function fit(map, groups) {
    var bounds = L.latLngBounds([]);
    groups.forEach(function (g) {
      if (g && g.getLayers().length) bounds.extend(g.getBounds());
    });
    if (bounds.isValid()) map.fitBounds(bounds, { padding: [24, 24], maxZoom: 18 });
    else map.setView([20, 0], 2);
  }

  window.CPCCAdminMap = {
    text: text,
    statusColor: statusColor,
    stationColor: STATION_COLOR,
    createMap: createMap,
    openRing: openRing,
    addAreas: addAreas,
    addStations: addStations,
    fit: fit
  };
})();
