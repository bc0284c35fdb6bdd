// The live map page (/map/): one CPCCMap on the socket the page names, and a status line.
// A file of its own rather than an inline script: the pages' Content Security Policy allows
// scripts from this site only.
(function () {
  'use strict';
  var element = document.getElementById('live-map');
  var status = document.getElementById('map-status');
  var map = new CPCCMap(element, {
    tiles: element.dataset.tiles || '',
    onDraw: function () {
      status.textContent = (element.dataset.connected === 'true' ? 'live' : 'reconnecting…') +
        ' · ' + element.dataset.vehicles + ' vehicle(s) · ' + element.dataset.tasksOpen +
        ' open, ' + element.dataset.tasksDone + ' done task(s)';
    }
  });
  window.cpccMap = map;
  map.connect(element.dataset.socket);
})();
