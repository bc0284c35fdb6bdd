/* The program editor (templates/missions/editor.html): CodeMirror with JavaScript highlighting
 * on the program box, "Check" (POST /vvs/check/, the same syntax check as the upload: the
 * error's line is marked in the editor), loading a .js file into the editor, and a check
 * before submitting, so that a program with a syntax error is shown, not sent (the server
 * checks again anyway).
 *
 * Planning before flying: a map of where the platform serves (GET /api/v1/service-area/: the
 * areas of the vehicles in service per altitude band, and the no-fly zones; no vehicle is
 * named), on which a click puts `new VV.types.LatLngAlt(lat, lng, alt)` at the editor's
 * cursor, at an altitude served there; and "Dry run" (POST /api/v1/vvs/dry-run/): the
 * program against a simulated copy of the fleet, whose report lists every task (those no
 * vehicle could serve with their line, a click away), how long it would take and whether a
 * quota would stop it. Its tasks show on the map too.
 *
 * State for whoever looks (tests): data-check on the form: "", "checking", "ok" or "error";
 * data-dry-run on the form: "", "running", "done" or "error"; data-state ("loading", "ready",
 * "error"), data-bands and data-zones on #service-map; window.cpccEditor is the CodeMirror
 * instance, window.cpccServiceMap the service area's CPCCMap (static/js/map.js). */
(function () {
  'use strict';

  document.addEventListener('DOMContentLoaded', function () {
    var form = document.getElementById('editor-form');
    if (!form) return;
    var textarea = form.querySelector('textarea[name=program]');
    var nameInput = form.querySelector('input[name=name]');
    var fileInput = form.querySelector('input[type=file]');
    var result = document.getElementById('check-result');
    var checkButton = document.getElementById('check-button');
    var csrf = form.querySelector('input[name=csrfmiddlewaretoken]').value;

    var editor = null;
    if (window.CodeMirror) {
      editor = window.CodeMirror.fromTextArea(textarea, {
        mode: 'javascript', lineNumbers: true, matchBrackets: true, indentUnit: 2, tabSize: 2,
        gutters: ['cm-error-gutter-col', 'CodeMirror-linenumbers'],
        extraKeys: { 'Ctrl-Enter': function () { check(); }, 'Cmd-Enter': function () { check(); } }
      });
      window.cpccEditor = editor;
    }
    function program() { return editor ? editor.getValue() : textarea.value; }
    function setProgram(text) { if (editor) editor.setValue(text); else textarea.value = text; }

    var marked = null; // {line, mark}
    function unmark() {
      if (!marked || !editor) { marked = null; return; }
      editor.removeLineClass(marked.line, 'background', 'cm-error-line');
      editor.setGutterMarker(marked.line, 'cm-error-gutter-col', null);
      if (marked.mark) marked.mark.clear();
      marked = null;
    }
    function mark(line, column) {
      unmark();
      if (!editor) return;
      var l = Math.max(0, Math.min(editor.lineCount() - 1, line - 1));
      var text = editor.getLine(l);
      var c = Math.max(0, Math.min(text.length, column - 1));
      editor.addLineClass(l, 'background', 'cm-error-line');
      var gutter = document.createElement('span');
      gutter.className = 'cm-error-gutter';
      gutter.textContent = '●';
      gutter.title = 'syntax error';
      editor.setGutterMarker(l, 'cm-error-gutter-col', gutter);
      var to = Math.min(text.length, c + 1);
      var m = to > c ? editor.markText({ line: l, ch: c }, { line: l, ch: to }, { className: 'cm-error-mark' }) : null;
      marked = { line: l, mark: m };
      editor.scrollIntoView({ line: l, ch: c }, 80);
      editor.setCursor({ line: l, ch: c });
    }

    function say(kind, text) {
      result.className = 'check-result' + (kind ? ' ' + kind : '');
      result.textContent = text;
    }

    var checkedText = null;
    function check() {
      var text = program();
      form.dataset.check = 'checking';
      say('', 'Checking…');
      checkButton.disabled = true;
      return fetch(form.dataset.checkUrl, {
        method: 'POST',
        credentials: 'same-origin',
        headers: { 'Content-Type': 'application/json', 'X-CSRFToken': csrf },
        body: JSON.stringify({ program: text })
      }).then(function (response) {
        if (!response.ok) throw new Error('the check answered ' + response.status);
        return response.json();
      }).then(function (answer) {
        checkedText = text;
        if (answer.ok) {
          unmark();
          form.dataset.check = 'ok';
          say('ok', 'No syntax error.');
        } else {
          mark(answer.line, answer.column);
          form.dataset.check = 'error';
          say('bad', 'Line ' + answer.line + ', column ' + answer.column + ': ' + answer.message);
        }
        return answer.ok;
      }).catch(function (error) {
        form.dataset.check = '';
        say('bad', 'Could not check the program (' + error.message + '); try again.');
        return null;
      }).then(function (ok) {
        checkButton.disabled = false;
        return ok;
      });
    }

    checkButton.addEventListener('click', function () { check(); });

    if (editor) {
      editor.on('change', function () {
        if (form.dataset.check) {
          unmark();
          form.dataset.check = '';
          say('', '');
        }
      });
    }

    if (fileInput) {
      fileInput.addEventListener('change', function () {
        var file = fileInput.files && fileInput.files[0];
        if (!file) return;
        file.text().then(function (text) {
          setProgram(text.replace(/^\ufeff/, ''));
          if (!nameInput.value.trim()) nameInput.value = file.name.replace(/\.m?js$/i, '');
          say('', 'Loaded ' + file.name + ' (' + text.split('\n').length + ' lines).');
          // The editor holds it now: do not upload the file as well.
          fileInput.value = '';
        });
      });
    }

    // Submit only a program that parses: check first (unless this very text was checked).
    form.addEventListener('submit', function (event) {
      if (editor) editor.save();
      if (checkedText === program() && form.dataset.check === 'ok') return;
      event.preventDefault();
      check().then(function (ok) {
        if (ok === true || ok === null) { // the server checks when we could not
          if (editor) editor.save();
          form.submit();
        }
      });
    });

    // A syntax error the server found (on submit): mark it as a check would.
    if (form.dataset.errorLine) {
      mark(Number(form.dataset.errorLine), Number(form.dataset.errorColumn || 1));
      form.dataset.check = 'error';
      checkedText = program();
    }

    var plan = servicePlan(document.getElementById('service-map'), insertAtCursor, goTo);
    dryRun(form, {
      program: program, name: function () { return nameInput.value.trim(); }, csrf: csrf,
      mark: mark, say: say, goTo: goTo, highlight: highlight, plan: plan
    });

    /* Put text where the cursor is (replacing a selection), and keep typing there. */
    function insertAtCursor(text) {
      if (editor) {
        editor.replaceSelection(text);
        editor.focus();
        return editor.getCursor().line + 1;
      }
      var start = textarea.selectionStart, end = textarea.selectionEnd;
      textarea.value = textarea.value.slice(0, start) + text + textarea.value.slice(end);
      textarea.selectionStart = textarea.selectionEnd = start + text.length;
      textarea.focus();
      return textarea.value.slice(0, start).split('\n').length;
    }

    /* Show a line of the program (1-based) marked, in view; the cursor stays where it is. */
    var shown = null;
    function highlight(line) {
      if (!editor) return null;
      var l = Math.max(0, Math.min(editor.lineCount() - 1, line - 1));
      if (shown !== null) editor.removeLineClass(shown, 'background', 'cm-dry-run-line');
      shown = editor.addLineClass(l, 'background', 'cm-dry-run-line');
      editor.scrollIntoView({ line: l, ch: 0 }, 80);
      return l;
    }

    /* Go to a place of the program (1-based line and column): marked, with the cursor. */
    function goTo(line, column) {
      var l = highlight(line);
      if (l === null) return;
      editor.setCursor({ line: l, ch: Math.max(0, (column || 1) - 1) });
      editor.focus();
    }
  });

  /* --- where the platform serves: the map ---------------------------------------------------- */

  var BAND_COLOR = '#6c5ce7'; // the operation areas' colour on the live map (map.js)
  var NO_FLY_COLOR = '#d62828';
  var TASK_COLOR = { servable: '#1f6fe5', unservable: '#d62828' };
  var PREFERRED_ALT_M = 30;

  function servicePlan(element, insert, goTo) {
    if (!element || !window.L || !window.CPCCMap) return null;
    var status = document.getElementById('service-map-status');
    var cpcc = new window.CPCCMap(element, { tiles: element.dataset.tiles || '' });
    window.cpccServiceMap = cpcc;
    var map = cpcc.map;
    var areas = L.layerGroup().addTo(map);
    var tasks = L.layerGroup().addTo(map);
    var bands = [], zones = [];
    var where = ''; // what the status line says of the place under the pointer

    function tell(text) { status.textContent = text; }

    fetch(element.dataset.url, { credentials: 'same-origin', headers: { Accept: 'application/json' } })
      .then(function (response) {
        if (!response.ok) throw new Error('the service area answered ' + response.status);
        return response.json();
      })
      .then(function (collection) {
        var bounds = L.latLngBounds([]);
        collection.features.forEach(function (feature) {
          var props = feature.properties;
          var layer = L.geoJSON(feature, {
            interactive: false,
            style: props.kind === 'no_fly'
              ? { color: NO_FLY_COLOR, weight: 1.5, dashArray: '4 4', fillColor: NO_FLY_COLOR, fillOpacity: 0.18 }
              : { color: BAND_COLOR, weight: 2, fillColor: BAND_COLOR, fillOpacity: 0.14 }
          }).addTo(areas);
          if (props.kind === 'no_fly') {
            zones.push(feature);
          } else {
            bands.push(feature);
            bounds.extend(layer.getBounds());
          }
        });
        element.dataset.bands = String(bands.length);
        element.dataset.zones = String(zones.length);
        element.dataset.state = 'ready';
        show(bounds);
        // How to click is the hint below the map, always shown; this line tells what is where.
        tell(bands.length ? 'Point at the map to see the altitudes served there.'
          : 'No vehicle is in service now: no task could be served anywhere.');
      })
      .catch(function (error) {
        element.dataset.state = 'error';
        show(L.latLngBounds([]));
        tell('Could not load the service area (' + error.message + ').');
      });

    /* The view: the service area (CPCCMap.fit, which shows the background once it has a
     * view; static/js/map.js). */
    function show(bounds) {
      if (bounds.isValid()) {
        cpcc.areaBounds = bounds;
        if (typeof cpcc.fit === 'function') cpcc.fit(); else map.fitBounds(bounds.pad(0.08));
      }
      if (typeof cpcc.redraw === 'function') cpcc.redraw();
    }

    map.on('click', function (event) {
      var lat = event.latlng.lat, lng = wrap(event.latlng.lng);
      var here = servedAt(lat, lng);
      var alt = altitudeFor(lat, lng, here);
      var text = 'new VV.types.LatLngAlt(' + lat.toFixed(6) + ', ' + lng.toFixed(6) + ', ' + alt + ')';
      var line = insert(text);
      tell('Inserted at line ' + line + ': ' + text + '. ' + describe(here, lat, lng, alt));
    });
    map.on('mousemove', function (event) {
      var lat = event.latlng.lat, lng = wrap(event.latlng.lng);
      var text = describe(servedAt(lat, lng), lat, lng, null);
      if (text !== where) { where = text; tell(text); }
    });

    function servedAt(lat, lng) {
      return bands.filter(function (f) { return covers(f.geometry, lat, lng); })
        .map(function (f) { return f.properties; })
        .sort(function (a, b) { return a.min_altitude_m - b.min_altitude_m; });
    }

    function forbidden(lat, lng, alt) {
      return zones.some(function (f) {
        var p = f.properties;
        return alt >= p.min_altitude_m && (p.max_altitude_m === null || alt <= p.max_altitude_m) &&
          covers(f.geometry, lat, lng);
      });
    }

    /* PREFERRED_ALT_M when it is served here, else the lowest altitude that is (clear of the
     * no-fly zones): a bound of a band or the top of a zone. */
    function altitudeFor(lat, lng, here) {
      var candidates = [PREFERRED_ALT_M];
      here.forEach(function (b) { candidates.push(b.min_altitude_m, b.max_altitude_m); });
      zones.forEach(function (f) {
        if (f.properties.max_altitude_m !== null) candidates.push(f.properties.max_altitude_m + 1);
      });
      var fine = candidates.filter(function (alt) {
        return here.some(function (b) { return alt >= b.min_altitude_m && alt <= b.max_altitude_m; }) &&
          !forbidden(lat, lng, alt);
      });
      if (fine.indexOf(PREFERRED_ALT_M) >= 0 || !fine.length) return PREFERRED_ALT_M;
      return Math.min.apply(null, fine);
    }

    function describe(here, lat, lng, alt) {
      if (!here.length) return 'Outside the service area: no vehicle in service could serve a task here.';
      var ranges = here.map(function (b) { return b.min_altitude_m + '–' + b.max_altitude_m + ' m'; });
      var text = 'Served here at ' + ranges.join(', ') + ' above ground';
      if (alt !== null && forbidden(lat, lng, alt)) text += ', but a no-fly zone holds ' + alt + ' m';
      else if (alt === null && zones.some(function (f) { return covers(f.geometry, lat, lng); })) text += ' (a no-fly zone is here)';
      return text + '.';
    }

    /* The dry run's tasks as dots: blue servable, red not; a click shows its line. */
    function showTasks(list) {
      tasks.clearLayers();
      list.forEach(function (task, k) {
        var servable = task.servable;
        var dot = L.circleMarker([task.position[0], task.position[1]], {
          renderer: cpcc.renderer, radius: 5, weight: 1, color: '#fff', fillOpacity: 0.95,
          fillColor: servable ? TASK_COLOR.servable : TASK_COLOR.unservable
        });
        var text = window.CPCCMap.text;
        dot.bindTooltip(text('Task ' + (k + 1) + (task.line ? ', line ' + task.line : '') +
          (servable ? '' : ': no vehicle could serve it')));
        if (task.line) dot.on('click', function () { goTo(task.line, task.column); });
        dot.addTo(tasks);
      });
      element.dataset.tasks = String(list.length);
    }

    return { showTasks: showTasks };
  }

  function wrap(lng) {
    return ((lng + 180) % 360 + 360) % 360 - 180;
  }

  /* Whether a GeoJSON Polygon or MultiPolygon ([lng, lat] rings) holds the point. */
  function covers(geometry, lat, lng) {
    var polygons = geometry.type === 'Polygon' ? [geometry.coordinates] : geometry.coordinates;
    return polygons.some(function (rings) {
      if (!inRing(rings[0], lat, lng)) return false;
      for (var h = 1; h < rings.length; h++) if (inRing(rings[h], lat, lng)) return false;
      return true;
    });
  }

  function inRing(ring, lat, lng) {
    var inside = false;
    for (var i = 0, j = ring.length - 1; i < ring.length; j = i++) {
      var xi = ring[i][0], yi = ring[i][1], xj = ring[j][0], yj = ring[j][1];
      if ((yi > lat) !== (yj > lat) && lng < (xj - xi) * (lat - yi) / (yj - yi) + xi) inside = !inside;
    }
    return inside;
  }

  /* --- the dry run ---------------------------------------------------------------------------- */

  function dryRun(form, page) {
    var button = document.getElementById('dry-run-button');
    var box = document.getElementById('dry-run');
    if (!button || !box) return;
    var summary = document.getElementById('dry-run-summary');
    var assumes = document.getElementById('dry-run-assumes');
    var verdicts = document.getElementById('dry-run-verdicts');
    var table = document.getElementById('dry-run-table');
    var rows = document.getElementById('dry-run-tasks');
    var logBox = document.getElementById('dry-run-log-box');
    var log = document.getElementById('dry-run-log');

    button.addEventListener('click', function () {
      form.dataset.dryRun = 'running';
      button.disabled = true;
      box.hidden = false;
      box.className = 'dry-run running';
      summary.textContent = 'Running the program against a simulated copy of the fleet…';
      verdicts.textContent = '';
      rows.textContent = '';
      table.hidden = true;
      logBox.hidden = true;
      fetch(form.dataset.dryRunUrl, {
        method: 'POST',
        credentials: 'same-origin',
        headers: { 'Content-Type': 'application/json', Accept: 'application/json', 'X-CSRFToken': page.csrf },
        body: JSON.stringify({ name: page.name() || 'dry run', program: page.program() })
      }).then(function (response) {
        return response.json().then(function (body) { return { status: response.status, body: body }; },
          function () { return { status: response.status, body: {} }; });
      }).then(function (answer) {
        if (answer.status === 200) {
          report(answer.body);
          form.dataset.dryRun = 'done';
          return;
        }
        var error = answer.body.error;
        if (answer.status === 400 && error && error.line) { // a syntax error, as Check shows it
          page.mark(error.line, error.column);
          form.dataset.check = 'error';
          page.say('bad', 'Line ' + error.line + ', column ' + error.column + ': ' + error.message);
        }
        fail(answer.body.detail || ('the dry run answered ' + answer.status));
      }).catch(function (error) {
        fail('could not reach the platform (' + error.message + '); try again');
      }).then(function () {
        button.disabled = false;
      });
    });

    function fail(text) {
      form.dataset.dryRun = 'error';
      box.className = 'dry-run bad';
      summary.textContent = 'No dry run: ' + text;
    }

    function report(r) {
      var ok = r.status === 'finished' && !r.unservable.length && r.within_quotas;
      box.className = 'dry-run ' + (ok ? 'ok' : 'bad');
      summary.textContent = r.tasks.length + ' task' + (r.tasks.length === 1 ? '' : 's') + ', ' +
        (r.unservable.length ? r.unservable.length + ' that no vehicle in service could serve'
          : 'every one servable') +
        ' · ' + ending(r) + ' after about ' + duration(r.duration_s) +
        (r.message_wait_s ? ' (not counting up to ' + duration(r.message_wait_s) +
          ' of waiting for messages)' : '') + '.';
      assumes.textContent = r.assumes || '';
      assumes.hidden = !r.assumes;
      verdicts.textContent = '';
      r.unservable.forEach(function (task) {
        var item = verdict('bad');
        item.appendChild(place(task.line, task.column));
        item.appendChild(document.createTextNode(' ' + task.message));
      });
      if (r.error && r.status === 'failed') {
        var failed = verdict('bad');
        if (r.error_line) failed.appendChild(place(r.error_line, r.error_column));
        var rejected = r.unservable.some(function (task) {
          return task.line === r.error_line && task.column === r.error_column;
        });
        failed.appendChild(document.createTextNode(rejected
          ? ' The program does not catch the TaskRejectedError there: it would fail.'
          : ' It would fail: ' + r.error));
      }
      var quota = verdict(r.within_quotas ? 'ok' : 'bad');
      if (r.within_quotas) {
        quota.textContent = 'Within your quotas.';
      } else {
        if (r.quota.line) quota.appendChild(place(r.quota.line, r.quota.column));
        quota.appendChild(document.createTextNode(' A quota would stop it after ' +
          r.quota.tasks_before + ' task(s): ' + r.quota.message));
      }
      if (r.status === 'unfinished') {
        verdict('bad').textContent = 'The dry run stopped at its time limit before the program ended: ' +
          'what it would do after is not known.';
      }
      r.tasks.forEach(function (task, k) { rows.appendChild(row(task, k)); });
      table.hidden = !r.tasks.length;
      log.textContent = r.log.join('\n');
      logBox.hidden = !r.log.length;
      if (page.plan) page.plan.showTasks(r.tasks);
      if (r.unservable.length && r.unservable[0].line) page.highlight(r.unservable[0].line);
    }

    function verdict(kind) {
      var item = document.createElement('li');
      item.className = kind;
      verdicts.appendChild(item);
      return item;
    }

    /* "line L:C", a button that shows that place of the program. */
    function place(line, column) {
      var link = document.createElement('button');
      link.type = 'button';
      link.className = 'line-link';
      link.textContent = 'line ' + line + (column ? ':' + column : '');
      link.addEventListener('click', function () { page.goTo(line, column); });
      return link;
    }

    function row(task, k) {
      var tr = document.createElement('tr');
      if (!task.servable) tr.className = 'unservable';
      var result = task.servable
        ? (task.status === 'done' ? 'read at ' + duration(task.done_s) : task.status)
        : 'no vehicle could serve it';
      var cells = [String(k + 1),
        task.position[0].toFixed(6) + ', ' + task.position[1].toFixed(6) + ', ' + task.position[2] + ' m',
        task.sensors.join(', '), null, result];
      cells.forEach(function (value) {
        var td = document.createElement('td');
        if (value === null) {
          if (task.line) td.appendChild(place(task.line, task.column));
        } else {
          td.textContent = value;
        }
        tr.appendChild(td);
      });
      return tr;
    }
  }

  function ending(r) {
    if (r.status === 'finished') return 'it would finish';
    if (r.status === 'failed') return 'it would fail';
    if (r.status === 'killed') return 'a quota would stop it';
    return 'still running when the dry run stopped';
  }

  function duration(seconds) {
    if (seconds === null || seconds === undefined) return '–';
    var s = Math.round(seconds);
    if (s < 60) return seconds.toFixed(1) + ' s';
    var m = Math.floor(s / 60);
    if (m < 60) return m + ' min ' + (s % 60) + ' s';
    return Math.floor(m / 60) + ' h ' + (m % 60) + ' min';
  }
})();
