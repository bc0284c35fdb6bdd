/* The fleet overview's map (fleet/admin.py, VehicleAdmin.overview_view): every RV that is not
   removed with its operation area and its position, named with the VVs aboard, and the ground
   stations. The data is the page's JSON (#fleet-overview-data); the table below the map has
   the same RVs. State for tests, on the map's element: data-state ("ready"), data-vehicles
   (RV markers drawn), data-areas, data-stations. */
(function () {
  'use strict';

  var M = window.CPCCAdminMap;

  function label(v) {
    var aboard = v.vvs_aboard === 1 ? '1 VV' : v.vvs_aboard + ' VVs';
    return v.name + ' · ' + aboard;
  }

  function popup(v) {
    var box = document.createElement('div');
    var name = document.createElement('strong');
    name.textContent = v.name;
    var link = document.createElement('a');
    link.href = v.url;
    link.textContent = 'change';
    box.append(name, document.createElement('br'), v.status + ', ' + v.phase + ' · ', link);
    return box;
  }

  function init(element) {
    var data = JSON.parse(document.getElementById(element.dataset.context).textContent);
    var map = M.createMap(element, element.dataset.tiles, { preferCanvas: true });
    var flying = data.vehicles.filter(function (v) { return v.status !== 'removed'; });
    var areas = M.addAreas(map, flying);
    var stations = M.addStations(map, data.stations, true);
    var vehicles = L.featureGroup();
    flying.forEach(function (v) {
      var color = M.statusColor(v.status);
      var marker = L.circleMarker([v.lat, v.lng], {
        radius: 7, color: '#ffffff', weight: 2, fillColor: color, fillOpacity: 1
      });
      marker.bindTooltip(M.text(label(v)), {
        permanent: true, direction: 'right', offset: [9, 0], className: 'cpcc-map-label'
      });
      marker.bindPopup(popup(v));
      marker.addTo(vehicles);
    });
    vehicles.addTo(map);
    M.fit(map, [areas, stations, vehicles]);
    element.dataset.vehicles = String(vehicles.getLayers().length);
    element.dataset.areas = String(areas.getLayers().length);
    element.dataset.stations = String(stations.getLayers().length);
    element.dataset.state = 'ready';
    window.CPCCFleetMap = map;
  }

  document.addEventListener('DOMContentLoaded', function () {
    document.querySelectorAll('[data-fleet-map]').forEach(init);
  });
})();
