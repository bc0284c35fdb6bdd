// The live map page (/map/): one CPCCMap on the socket the page names, a status line, and the
// filters: how much history it shows (staff start with the last 15 minutes, customers with
// the last hour) and which VVs: the running ones (the default), every one, or one VV alone
// with its whole history, fetched from the server (/vvs/<id>/map.json: staff may see any VV,
// a customer only its own).
// State for whoever looks, on #live-map besides CPCCMap's: data-window (seconds, empty for
// all), data-running (only the VVs that have not ended), data-only (the VV shown alone),
// data-history-of (the VV whose history has come).
// A file of its own rather than an inline script: the pages' Content Security Policy allows
// scripts from this site only.
(function () {
  'use strict';
  var REDRAW_MS = 15000; // what leaves the time window goes, frames or not
  var ENDED = { finished: true, failed: true, killed: true, cancelled: true };
  var RUNNING = 'running'; // the VV choice that shows those that have not ended

  var element = document.getElementById('live-map');
  var status = document.getElementById('map-status');
  var windowChoice = document.getElementById('map-window');
  var vvChoice = document.getElementById('map-vv');
  var vvStatus = document.getElementById('map-vv-status');
  var listed = ''; // the VVs the choice lists, as a key: rebuilt only when they change

  /* The choice of VVs: every one the map knows, by name (ended ones say so). */
  function listVVs(map) {
    var vvs = Object.keys(map.vvs).map(function (id) { return map.vvs[id]; })
      .filter(function (vv) { return vv.name; });
    vvs.sort(function (a, b) { return a.name.localeCompare(b.name) || (a.id < b.id ? -1 : 1); });
    var names = {};
    vvs.forEach(function (vv) { names[vv.name] = (names[vv.name] || 0) + 1; });
    var labels = vvs.map(function (vv) {
      // Two VVs of one name (staff see every customer's) are told apart by their id.
      var label = vv.name + (names[vv.name] > 1 ? ' · ' + vv.id.slice(0, 8) : '');
      return ENDED[vv.status] ? label + ' (' + vv.status + ')' : label;
    });
    var key = vvs.map(function (vv, k) { return vv.id + '=' + labels[k]; }).join('\n');
    if (key === listed) return;
    listed = key;
    var chosen = vvChoice.value;
    while (vvChoice.options.length > 2) vvChoice.remove(2);
    vvs.forEach(function (vv, k) {
      var option = document.createElement('option');
      option.value = vv.id;
      option.textContent = labels[k];
      vvChoice.appendChild(option);
    });
    vvChoice.value = chosen;
    if (vvChoice.selectedIndex < 0) vvChoice.value = '';
  }

  var map = new CPCCMap(element, {
    tiles: element.dataset.tiles || '',
    onDraw: function () {
      var idle = element.dataset.running === 'true' && element.dataset.vvsShown === '0' &&
        element.dataset.vvs !== '0';
      status.textContent = (element.dataset.connected === 'true' ? 'live' : 'reconnecting…') +
        ' · ' + element.dataset.vehicles + ' vehicle(s) · ' + element.dataset.tasksOpen +
        ' open, ' + element.dataset.tasksDone + ' done task(s)' +
        (idle ? ' · none running now: "every one" shows those that have ended' : '');
      listVVs(map);
    }
  });
  window.cpccMap = map;

  map.setWindow(windowChoice.value);
  element.dataset.window = windowChoice.value;
  // "the running ones" (the first choice, and the default): the VVs that have not ended.
  map.showRunning(vvChoice.value === RUNNING);
  element.dataset.running = String(vvChoice.value === RUNNING);
  windowChoice.addEventListener('change', function () {
    map.setWindow(windowChoice.value);
    element.dataset.window = windowChoice.value;
  });

  /* One VV alone, with all the server keeps of it; or every VV again, or the running ones. */
  vvChoice.addEventListener('change', function () {
    var running = vvChoice.value === RUNNING;
    var id = running ? '' : vvChoice.value;
    map.showRunning(running);
    element.dataset.running = String(running);
    map.showOnly(id || null);
    element.dataset.only = id;
    if (!id) {
      vvStatus.textContent = '';
      map.fit();
      return;
    }
    windowChoice.value = '';
    windowChoice.dispatchEvent(new Event('change'));
    vvStatus.textContent = 'loading its whole history…';
    element.dataset.historyOf = '';
    var url = element.dataset.history.replace(element.dataset.historyPlaceholder, id);
    fetch(url, { credentials: 'same-origin' })
      .then(function (response) {
        if (!response.ok) throw new Error('answered ' + response.status);
        return response.json();
      })
      .then(function (snapshot) {
        if (vvChoice.value !== id) return; // another choice was made meanwhile
        map.mergeHistory(snapshot);
        map.fit();
        vvStatus.textContent = 'its whole history';
        element.dataset.historyOf = id;
      })
      .catch(function (error) {
        vvStatus.textContent = 'its history could not be loaded (' + error.message + ')';
      });
  });

  setInterval(function () { map.redraw(); }, REDRAW_MS);
  map.connect(element.dataset.socket);
})();
