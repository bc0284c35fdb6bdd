/* The live map (missions/consumers.py sends what it shows; missions/events.py the shapes).
 *
 * CPCCMap draws, on a Leaflet map with its canvas renderer: operation areas, ground stations,
 * vehicles (with their name and the VVs aboard for staff), planned vehicle routes (gray), the
 * paths of VVs while carried (green), the paths VVs intend to take (light blue), done tasks
 * (red dots), open tasks (blue dots), migrations (red lines) and, live, each message one VV
 * sends another (a magenta dashed line from the sender to the recipient where they are when it
 * comes, gone after MESSAGE_LINE_MS). It is fed snapshots and frames, live from the socket
 * (connect) or from a mission's history (replay).
 *
 * Its state is on the map element for whoever looks (tests, the page): data-seq (last frame),
 * data-connected, data-vehicles, data-tasks-open, data-tasks-done, data-tasks-refused (points
 * drawn that no vehicle may fly to), data-vvs (every VV it
 * knows), data-vvs-shown (those with something in view), data-frames, data-tiles-loaded,
 * data-messages (message lines drawn so far), data-messages-shown (those on the map now).
 *
 * The background is the tile server of the CPCC_MAP_TILES setting, or else the platform's own
 * tiles of the simulated world (/tiles/{z}/{x}/{y}.png: what the cameras photograph). The map
 * fits, once, the operation areas and the tasks the platform accepted: a point no vehicle
 * may fly to (a rejected task, drawn as a dashed ring) never pulls the view away from the
 * fleet, unless the map is one VV's (option fitRefused: its page shows why it failed).
 *
 * What it shows can be narrowed (the live map's filters): setWindow(seconds) keeps the
 * history (paths, done tasks, migrations) of that last stretch of time, open tasks and
 * vehicles always; showRunning(true) the VVs that have not ended; showOnly(vv) one VV;
 * mergeHistory(snapshot) adds what the server keeps of a VV (/vvs/<id>/map.json) to what the
 * socket brought. Live, the history older than FADE_S is drawn faint (option fade: false, as
 * on a VV's own page, draws it all alike).
 *
 * Names (VVs, vehicles, areas, ground stations) are the customers' and operators' words, never
 * markup: every tooltip is a DOM node whose text is set by text() (Leaflet would take a string
 * as HTML).
 *
 * Each vehicle is drawn with the symbol of its kind (fleet/kinds.py; a state without one is
 * aerial): a copter's four rotors, a rover on its wheels, a boat's hull and sail, a submarine's
 * hull and tower, whose label says its depth ("Sub · -5 m"). The symbols are paths drawn by
 * the map's own renderer (KindMarker, canvas or SVG), nothing loaded; the admin's fleet
 * overview draws with them too (CPCCMap.kindMarker). State: data-vehicle-kinds, the vehicles
 * drawn per kind ("aerial:2,surface:1"), and each marker's options.kind.
 */
(function () {
  'use strict';

  var COLOR = {
    area: '#6c5ce7',
    station: '#2d3436',
    vehicle: '#e17055',
    route: '#8d99ae',
    carried: '#2a9d3a',
    intended: '#7ec8f5',
    done: '#d62828',
    open: '#1f6fe5',
    migration: '#d62828',
    message: '#c026d3',
    refused: '#7a1f1f'
  };
  var FADE_S = 600;   // live, the path flown before the last ten minutes is drawn faint...
  var FADED = 0.35;   // ...at this opacity, as are the done tasks and migrations of that time
  var MESSAGE_LINE_MS = 6000; // a message's line is on the map this long...
  var MESSAGE_FADE_MS = 2000; // ...fading out over the last of it
  var MESSAGE_TICK_MS = 100;
  var LABELS_UP_TO = 60; // permanent vehicle labels only while they stay readable
  var PLATFORM_TILES = '/tiles/{z}/{x}/{y}.png'; // fleet/views.py: the simulated world
  var MAX_ZOOM = 21;

  // --- vehicle kinds ------------------------------------------------------------------------

  var KINDS = ['aerial', 'ground', 'surface', 'underwater']; // fleet/kinds.py
  var KIND_COLOR = {
    aerial: COLOR.vehicle, ground: '#8d5524', surface: '#0077b6', underwater: '#f4b400'
  };
  var KIND_RADIUS = 10; // a symbol needs more room than a dot to be told apart
  // Each kind's symbol in units of the marker's radius (x right, y down, within [-1, 1]):
  // circles [x, y, r], ellipses [x, y, rx, ry] and polygons (a list of points, clockwise on the
  // screen so that the parts fill as one under the nonzero rule).
  var SYMBOLS = {
    aerial: { // a quadcopter from above: four rotors round a body
      circles: [[-0.58, -0.58, 0.42], [0.58, -0.58, 0.42], [0.58, 0.58, 0.42],
                [-0.58, 0.58, 0.42], [0, 0, 0.42]]
    },
    ground: { // a rover from the side: a body and a cab on two wheels
      polygons: [[[-0.95, -0.35], [-0.45, -0.35], [-0.25, -0.85], [0.4, -0.85], [0.6, -0.35],
                  [0.95, -0.35], [0.95, 0.35], [-0.95, 0.35]]],
      circles: [[-0.52, 0.5, 0.34], [0.52, 0.5, 0.34]]
    },
    surface: { // a boat: a hull under a sail
      polygons: [[[-1, 0.2], [1, 0.2], [0.6, 0.8], [-0.6, 0.8]],
                 [[0.05, -0.95], [0.8, 0.1], [0.05, 0.1]]]
    },
    underwater: { // a submarine: a long hull, its tower and its rudder
      ellipses: [[-0.08, 0.25, 0.88, 0.42]],
      polygons: [[[-0.35, -0.55], [0.15, -0.55], [0.25, 0], [-0.35, 0]],
                 [[0.7, 0.25], [1, -0.15], [1, 0.65]]]
    }
  };

  function kindOf(v) {
    return SYMBOLS[v.kind] ? v.kind : 'aerial';
  }

  /* Metres, as a label shows them: "-5 m" (never "-0 m"). */
  function metres(value) {
    var m = Math.round(value);
    return (m === 0 ? 0 : m) + ' m';
  }

  /* What a vehicle's label adds to its name: an underwater vehicle's depth. */
  function depthNote(v) {
    return kindOf(v) === 'underwater' && typeof v.alt === 'number' ? ' · ' + metres(v.alt) : '';
  }

  /* A circle marker drawn as its kind's symbol (options.kind), on a canvas or an SVG renderer;
   * it is found under the pointer as the circle of its radius. */
  var KindMarker = L.CircleMarker.extend({
    options: { kind: 'aerial', radius: KIND_RADIUS, fillRule: 'nonzero', lineJoin: 'round' },

    _updatePath: function () {
      var symbol = SYMBOLS[this.options.kind] || SYMBOLS.aerial;
      var renderer = this._renderer;
      if (renderer._ctx) {
        if (!renderer._drawing || this._empty()) return;
        var ctx = renderer._ctx;
        ctx.beginPath();
        trace(symbol, this._point, this._radius, canvasPen(ctx));
        renderer._fillStroke(ctx, this);
      } else {
        var d = [];
        if (!this._empty()) trace(symbol, this._point.round(), this._radius, svgPen(d));
        renderer._setPath(this, d.length ? d.join('') : 'M0 0');
      }
    }
  });

  /* The symbol's outline, drawn with a pen (a canvas's or an SVG path's) at `at`, `r` px. */
  function trace(symbol, at, r, pen) {
    var i;
    for (i = 0; i < (symbol.polygons || []).length; i++) {
      var points = symbol.polygons[i];
      for (var k = 0; k < points.length; k++) {
        pen(k ? 'L' : 'M', at.x + points[k][0] * r, at.y + points[k][1] * r);
      }
      pen('Z');
    }
    var ellipses = (symbol.circles || []).map(function (c) { return [c[0], c[1], c[2], c[2]]; })
      .concat(symbol.ellipses || []);
    for (i = 0; i < ellipses.length; i++) {
      var e = ellipses[i];
      pen('E', at.x + e[0] * r, at.y + e[1] * r, e[2] * r, e[3] * r);
    }
  }

  function canvasPen(ctx) {
    return function (op, x, y, rx, ry) {
      if (op === 'M') ctx.moveTo(x, y);
      else if (op === 'L') ctx.lineTo(x, y);
      else if (op === 'Z') ctx.closePath();
      else { ctx.moveTo(x + rx, y); ctx.ellipse(x, y, rx, ry, 0, 0, 2 * Math.PI, false); }
    };
  }

  function svgPen(d) {
    var n = function (v) { return Math.round(v * 10) / 10; };
    return function (op, x, y, rx, ry) {
      if (op === 'Z') d.push('Z');
      else if (op !== 'E') d.push(op + n(x) + ',' + n(y));
      else { // two half arcs, clockwise
        var arc = 'A' + n(rx) + ',' + n(ry) + ' 0 1,1 ';
        d.push('M' + n(x - rx) + ',' + n(y) + arc + n(x + rx) + ',' + n(y) + arc + n(x - rx) +
               ',' + n(y) + 'Z');
      }
    };
  }

  /* A vehicle's marker: its kind's symbol at latlng (options as L.circleMarker's). */
  function kindMarker(latlng, kind, options) {
    var known = SYMBOLS[kind] ? kind : 'aerial';
    return new KindMarker(latlng, L.extend({}, options || {}, { kind: known }));
  }

  /* Tooltip content from text: a node Leaflet shows as it is. */
  function text(value) {
    var span = document.createElement('span');
    span.textContent = value;
    return span;
  }

  function CPCCMap(element, options) {
    options = options || {};
    this.element = element;
    this.options = options;
    this.renderer = L.canvas({ padding: 0.3 });
    this.map = L.map(element, {
      preferCanvas: true, renderer: this.renderer, zoomSnap: 0.25, maxZoom: MAX_ZOOM
    });
    this.tiles = this._tileLayer(options);
    this.layers = {};
    var order = ['areas', 'stations', 'routes', 'intended', 'carried', 'migrations', 'messages',
                 'tasks', 'vehicles'];
    for (var i = 0; i < order.length; i++) {
      this.layers[order[i]] = L.layerGroup().addTo(this.map);
    }
    this.vvs = {};        // id -> {id, name, status, host_kind, tasks: {id: task}, track, migrations}
    this.vehicles = {};   // id -> state
    this.vehicleMarkers = {};
    this.vehicleLabels = {}; // id -> the text of its marker's label
    this.staff = false;
    this.seq = 0;
    this.frames = 0;
    this.messageLines = []; // {line, at}: the messages' lines on the map, oldest first
    this.messagesDrawn = 0;
    this._fading = null;    // the timer that fades them while there are any
    this.time = null;     // replay: show the mission as it was at this time (seconds)
    this.window = null;   // live: show the history of only this many last seconds
    this.only = null;     // show this VV (its id) alone
    this.clockOffset = 0; // the platform's clock minus this browser's (seconds)
    this._since = null;   // while drawing: the start of the window on the platform's clock
    this.areaBounds = L.latLngBounds([]);
    this.stationBounds = L.latLngBounds([]);
    this._fitted = false;
    this._snapshots = 0;  // applied so far: the first decides the view the tiles are shown in
    this._dirty = false;
    this.map.setView([0, 0], 2);
    // The background comes with the first view the page sets (a fit, here or by the page
    // that made the map), or with the first snapshot when there is nothing to fit.
    this.map.once('moveend', this.showTiles, this);
  }

  /* The background: not on the map before its first view is set (tiles of the provisional
   * world view would be asked for, then dropped half-loaded): see showTiles. */
  CPCCMap.prototype._tileLayer = function (options) {
    var own = !options.tiles;
    var layer = L.tileLayer(options.tiles || PLATFORM_TILES, {
      // The platform draws its world to zoom 19 (fleet/views.py), as most tile servers do:
      // deeper, the map enlarges those tiles.
      maxZoom: MAX_ZOOM, maxNativeZoom: 19,
      attribution: own ? 'Background: the simulated world' : (options.attribution || '')
    });
    var el = this.element;
    el.dataset.tilesLoaded = '0';
    layer.on('tileload', function () {
      el.dataset.tilesLoaded = String(Number(el.dataset.tilesLoaded) + 1);
    });
    layer.on('load', function () { el.dataset.tilesIdle = 'true'; });
    layer.on('loading', function () { el.dataset.tilesIdle = 'false'; });
    return layer;
  };

  /* Put the background on the map (once); a page that uses the map without snapshots calls
   * it if it never sets a view of its own. */
  CPCCMap.prototype.showTiles = function () {
    if (!this.map.hasLayer(this.tiles)) this.tiles.addTo(this.map);
  };

  CPCCMap.prototype.applySnapshot = function (snapshot) {
    this.staff = !!snapshot.staff;
    this.seq = snapshot.seq || 0;
    if (typeof snapshot.now === 'number') this.clockOffset = snapshot.now - Date.now() / 1000;
    this._snapshots += 1;
    this.vvs = {};
    for (var i = 0; i < (snapshot.vvs || []).length; i++) {
      var vv = snapshot.vvs[i];
      var entry = this._vv(vv.vv);
      entry.name = vv.name;
      entry.status = vv.status;
      entry.host_kind = vv.host_kind;
      entry.host = vv.host;
      for (var t = 0; t < vv.tasks.length; t++) entry.tasks[vv.tasks[t].id] = vv.tasks[t];
      entry.migrations = vv.migrations.slice();
      entry.track = vv.track.slice();
    }
    this.vehicles = {};
    this._vehicles(snapshot.vehicles || [], []);
    this._drawStatic(snapshot.areas || [], snapshot.stations || []);
    this._changed();
  };

  CPCCMap.prototype.applyFrame = function (frame) {
    this.seq = frame.seq;
    this.frames += 1;
    var events = frame.events || [];
    var messages = [];
    for (var i = 0; i < events.length; i++) {
      if (events[i].kind === 'message') messages.push(events[i]);
      else this._event(events[i]);
    }
    this._vehicles(frame.vehicles || [], frame.gone || []);
    // Where the VVs are once the frame's positions are in.
    for (var m = 0; m < messages.length; m++) this._message(messages[m]);
    this._changed();
  };

  CPCCMap.prototype._vv = function (id) {
    if (!this.vvs[id]) {
      this.vvs[id] = { id: id, name: '', status: '', tasks: {}, track: [], migrations: [] };
    }
    return this.vvs[id];
  };

  // What has ended does not start again: each worker publishes its changes in its own order,
  // so the word that a VV or task ended may arrive before an older word about it, which is
  // then kept out.
  var VV_ENDED = { finished: true, failed: true, killed: true, cancelled: true };

  CPCCMap.prototype._event = function (e) {
    var vv = this._vv(e.vv);
    if (e.kind === 'vv') {
      if (VV_ENDED[vv.status] && !VV_ENDED[e.status]) return;
      vv.name = e.name; vv.status = e.status; vv.host_kind = e.host_kind; vv.host = e.host;
    } else if (e.kind === 'task') {
      var known = vv.tasks[e.id];
      if (known && known.status !== 'open' && e.status === 'open') return;
      vv.tasks[e.id] = e;
    } else if (e.kind === 'migration') {
      for (var i = 0; i < vv.migrations.length; i++) if (vv.migrations[i].id === e.id) return;
      vv.migrations.push(e);
    }
  };

  /* Where a VV is on the map now: the vehicle carrying it, else the ground station it waits
   * on (gsPos, from the event); null when the map does not know the VV or cannot place it. */
  CPCCMap.prototype._where = function (vvId, gsPos) {
    if (!this.vvs[vvId]) return null;
    for (var id in this.vehicles) {
      var aboard = this.vehicles[id].vvs || [];
      for (var k = 0; k < aboard.length; k++) {
        if (aboard[k].id === vvId) return [this.vehicles[id].lat, this.vehicles[id].lng];
      }
    }
    return gsPos || null;
  };

  /* A message from one VV to another, live: a dashed line between the two for
   * MESSAGE_LINE_MS. Nothing when either is not on the map (or is not the VV shown alone), for
   * a message to itself, or in a replay. */
  CPCCMap.prototype._message = function (e) {
    if (this.time !== null || e.vv === e.to_vv) return;
    if (this.only && this.only !== e.vv && this.only !== e.to_vv) return;
    var from = this._where(e.vv, e.gs_pos);
    var to = this._where(e.to_vv, e.to_gs_pos);
    if (!from || !to) return;
    var line = L.polyline([from, to], {
      renderer: this.renderer, color: COLOR.message, weight: 3, opacity: 0.9, dashArray: '8 6'
    }).bindTooltip(text(e.name + ' → ' + e.to_name + ': a message'));
    line.addTo(this.layers.messages);
    this.messageLines.push({ line: line, at: Date.now() });
    this.messagesDrawn += 1;
    this._messageState();
    var self = this;
    if (this._fading === null) {
      this._fading = setInterval(function () { self._fadeMessages(); }, MESSAGE_TICK_MS);
    }
  };

  /* The messages' lines fade out as they age, and go. */
  CPCCMap.prototype._fadeMessages = function () {
    var now = Date.now();
    var kept = [];
    for (var i = 0; i < this.messageLines.length; i++) {
      var shown = this.messageLines[i];
      var left = MESSAGE_LINE_MS - (now - shown.at);
      if (left <= 0) {
        this.layers.messages.removeLayer(shown.line);
        continue;
      }
      if (left < MESSAGE_FADE_MS) shown.line.setStyle({ opacity: 0.9 * left / MESSAGE_FADE_MS });
      kept.push(shown);
    }
    this.messageLines = kept;
    if (!kept.length) {
      clearInterval(this._fading);
      this._fading = null;
    }
    this._messageState();
  };

  CPCCMap.prototype._messageState = function () {
    this.element.dataset.messages = String(this.messagesDrawn);
    this.element.dataset.messagesShown = String(this.messageLines.length);
  };

  CPCCMap.prototype._vehicles = function (states, gone) {
    for (var i = 0; i < states.length; i++) {
      var v = states[i];
      var previous = this.vehicles[v.id];
      this.vehicles[v.id] = v;
      // What a carried VV travels is the vehicle's path: extend its green line.
      for (var k = 0; k < (v.vvs || []).length; k++) {
        var vv = this._vv(v.vvs[k].id);
        if (!vv.name) vv.name = v.vvs[k].name;
        var last = vv.track[vv.track.length - 1];
        if (!last || last[1] !== v.lat || last[2] !== v.lng) vv.track.push([v.t, v.lat, v.lng]);
      }
      if (previous && previous.lat === v.lat && previous.lng === v.lng) continue;
    }
    for (var g = 0; g < gone.length; g++) delete this.vehicles[gone[g]];
  };

  CPCCMap.prototype._changed = function () {
    if (this._dirty) return;
    this._dirty = true;
    var self = this;
    var draw = function () { self._dirty = false; self._draw(); };
    if (window.requestAnimationFrame && !document.hidden) window.requestAnimationFrame(draw);
    else setTimeout(draw, 0);
  };

  CPCCMap.prototype._drawStatic = function (areas, stations) {
    var bounds = L.latLngBounds([]);
    var stationBounds = L.latLngBounds([]);
    this.layers.areas.clearLayers();
    this.layers.stations.clearLayers();
    for (var i = 0; i < areas.length; i++) {
      var polygon = L.polygon(areas[i].area, {
        renderer: this.renderer, color: COLOR.area, weight: 2, dashArray: '6 4',
        fillColor: COLOR.area, fillOpacity: 0.06
      });
      if (areas[i].name) polygon.bindTooltip(text(areas[i].name + ' (' + areas[i].status + ')'));
      polygon.addTo(this.layers.areas);
      bounds.extend(polygon.getBounds());
    }
    for (var s = 0; s < stations.length; s++) {
      var gs = stations[s];
      var marker = L.circleMarker([gs.lat, gs.lng], {
        renderer: this.renderer, radius: 7, color: COLOR.station, weight: 2,
        fillColor: '#fff', fillOpacity: 1
      });
      marker.bindTooltip(text(gs.name ? 'Ground station ' + gs.name : 'Ground station'));
      marker.addTo(this.layers.stations);
      stationBounds.extend([gs.lat, gs.lng]);
    }
    this.areaBounds = bounds;
    this.stationBounds = stationBounds;
  };

  /* The tasks a vehicle may fly to: every one but those refused (outside every operation
   * area, out of the altitude band, a sensor no vehicle has). */
  function accepted(task) {
    return task.status !== 'rejected';
  }

  /* What the view should hold: the operation areas and the accepted tasks (of the VV shown
   * alone, when one is: its path too); the ground stations when there is nothing else. */
  CPCCMap.prototype.boundsOfInterest = function () {
    var bounds = L.latLngBounds([]);
    if (!this.only) bounds.extend(this.areaBounds);
    for (var id in this.vvs) {
      if (this.only && id !== this.only) continue;
      var vv = this.vvs[id];
      for (var t in vv.tasks) {
        if (accepted(vv.tasks[t]) || this.options.fitRefused) {
          bounds.extend([vv.tasks[t].lat, vv.tasks[t].lng]);
        }
      }
      if (this.only) {
        for (var p = 0; p < vv.track.length; p++) bounds.extend([vv.track[p][1], vv.track[p][2]]);
      }
    }
    if (!bounds.isValid() && this.only) bounds.extend(this.areaBounds);
    if (!bounds.isValid()) bounds.extend(this.stationBounds);
    return bounds;
  };

  /* Fit the view to what matters; false when there is nothing to fit to yet. */
  CPCCMap.prototype.fit = function () {
    var bounds = this.boundsOfInterest();
    if (!bounds.isValid()) return false;
    this.map.fitBounds(bounds.pad(0.08), { maxZoom: 19, animate: false });
    this._fitted = true;
    return true;
  };

  // Only what had happened by the replay's time (everything when live), and, with a time
  // window, what happened within it.
  CPCCMap.prototype._seen = function (t) {
    if (this._since !== null && !(t !== null && t !== undefined && t >= this._since)) return false;
    return this.time === null || (t !== null && t !== undefined && t <= this.time);
  };

  /* Seconds on the platform's clock now (as far as this browser can tell). */
  CPCCMap.prototype.now = function () {
    return Date.now() / 1000 + this.clockOffset;
  };

  /* Show the history of the last `seconds` only (null: all of it). */
  CPCCMap.prototype.setWindow = function (seconds) {
    this.window = seconds === null || seconds === undefined || seconds === '' ? null
      : Number(seconds);
    this._changed();
  };

  /* Draw again (what has left the time window goes). */
  CPCCMap.prototype.redraw = function () {
    this._changed();
  };

  /* Show one VV alone (its id), or every VV again (null). */
  CPCCMap.prototype.showOnly = function (vvId) {
    this.only = vvId || null;
    this._changed();
  };

  /* Show only the VVs that have not ended (true), or the ended ones too (false). */
  CPCCMap.prototype.showRunning = function (running) {
    this.runningOnly = !!running;
    this._changed();
  };

  /* Add a VV's history as the server keeps it (the shape of a snapshot's "vvs") to what the
   * map knows: its tasks (a newer word from the socket stays), its whole path, its
   * migrations. */
  CPCCMap.prototype.mergeHistory = function (snapshot) {
    var list = snapshot.vvs || [];
    for (var i = 0; i < list.length; i++) {
      var kept = list[i];
      var entry = this._vv(kept.vv);
      if (!entry.name) entry.name = kept.name;
      if (!entry.status) entry.status = kept.status;
      for (var t = 0; t < kept.tasks.length; t++) {
        var known = entry.tasks[kept.tasks[t].id];
        if (!known || known.status === 'open') entry.tasks[kept.tasks[t].id] = kept.tasks[t];
      }
      var seen = {};
      for (var m = 0; m < entry.migrations.length; m++) seen[entry.migrations[m].id] = true;
      for (m = 0; m < kept.migrations.length; m++) {
        if (!seen[kept.migrations[m].id]) entry.migrations.push(kept.migrations[m]);
      }
      entry.migrations.sort(function (a, b) { return a.at_s - b.at_s; });
      var track = entry.track.concat(kept.track);
      track.sort(function (a, b) { return a[0] - b[0]; });
      entry.track = track.filter(function (p, k) {
        var q = track[k - 1];
        return !q || q[0] !== p[0] || q[1] !== p[1] || q[2] !== p[2];
      });
    }
    this._changed();
  };

  /* A VV's path as shown: within the window, from the leg it was on when the window began. */
  CPCCMap.prototype._path = function (track) {
    return this._paths(track, null).recent;
  };

  /* A track's points in view, as the part flown before ``fadeFrom`` (platform seconds; null:
   * none) and the part after it, which share the point where one ends and the other starts. */
  CPCCMap.prototype._paths = function (track, fadeFrom) {
    var old = [], recent = [];
    for (var p = 0; p < track.length; p++) {
      var t = track[p][0];
      var next = track[p + 1];
      if (!(this._seen(t) || (this._since !== null && next && next[0] >= this._since))) continue;
      var point = [track[p][1], track[p][2]];
      if (fadeFrom !== null && next && next[0] <= fadeFrom) {
        old.push(point);
      } else {
        if (fadeFrom !== null && t < fadeFrom) old.push(point);
        recent.push(point);
      }
    }
    return { old: old, recent: recent };
  };

  CPCCMap.prototype._draw = function () {
    if (!this._fitted) this.fit();
    if (this._snapshots) this.showTiles();
    var L_ = this.layers;
    L_.tasks.clearLayers(); L_.carried.clearLayers(); L_.intended.clearLayers();
    L_.migrations.clearLayers(); L_.routes.clearLayers();
    this._since = this.window === null || this.time !== null ? null : this.now() - this.window;
    var open = 0, done = 0, refused = 0, count = 0, shown = 0;
    for (var id in this.vvs) {
      var vv = this.vvs[id];
      count += 1;
      if (this.only && id !== this.only) continue;
      if (this.runningOnly && !this.only && VV_ENDED[vv.status]) continue;
      var before = open + done, moves = 0;
      // Live, what was flown more than FADE_S ago is drawn faint: the last minutes stand out.
      var fadeFrom = this.time === null && !this.only && this.options.fade !== false
        ? this.now() - FADE_S : null;
      var paths = this._paths(vv.track, fadeFrom);
      var path = paths.recent;
      if (paths.old.length > 1) {
        L.polyline(paths.old, {
          renderer: this.renderer, color: COLOR.carried, weight: 2, opacity: FADED
        }).bindTooltip(text(vv.name)).addTo(L_.carried);
      }
      if (path.length > 1) {
        L.polyline(path, { renderer: this.renderer, color: COLOR.carried, weight: 3 })
          .bindTooltip(text(vv.name)).addTo(L_.carried);
      }
      var pending = [];
      for (var tid in vv.tasks) {
        var task = vv.tasks[tid];
        var name = vv.name + ': task ' + task.q + (task.index ? '.' + task.index : '');
        if (task.status === 'rejected') {
          // A point no vehicle may fly to: a hollow dashed ring where it is (the VV's page
          // says why).
          if (this.time !== null && !this._seen(task.requested_s)) continue;
          refused += 1;
          L.circleMarker([task.lat, task.lng], {
            renderer: this.renderer, radius: 6, color: COLOR.refused, weight: 2.5,
            dashArray: '3 3', fillColor: '#fff', fillOpacity: 0.9
          }).bindTooltip(text(name + ' (refused)')).addTo(L_.tasks);
          continue;
        }
        var isDone = task.status === 'done' && this._seen(task.done_s);
        var isOpen = this.time === null ? task.status === 'open'
          : this._seen(task.requested_s) && !isDone && task.status !== 'rejected'
            && task.status !== 'cancelled';
        if (!isDone && !isOpen) continue;
        if (isDone) done += 1; else { open += 1; pending.push(task); }
        L.circleMarker([task.lat, task.lng], {
          renderer: this.renderer, radius: 4, stroke: false,
          fillOpacity: isDone && fadeFrom !== null && task.done_s < fadeFrom ? FADED : 0.9,
          fillColor: isDone ? COLOR.done : COLOR.open
        }).bindTooltip(text(name + (isDone ? ' (done)' : ' (open)')))
          .addTo(L_.tasks);
      }
      if (pending.length && path.length) {
        pending.sort(function (a, b) { return a.q - b.q || a.index - b.index; });
        var intended = [path[path.length - 1]];
        for (var n = 0; n < pending.length; n++) intended.push([pending[n].lat, pending[n].lng]);
        L.polyline(intended, {
          renderer: this.renderer, color: COLOR.intended, weight: 2, dashArray: '4 6'
        }).addTo(L_.intended);
      }
      for (var m = 0; m < vv.migrations.length; m++) {
        var move = vv.migrations[m];
        if (!move.from_pos || !move.to_pos || !this._seen(move.at_s)) continue;
        moves += 1;
        L.polyline([move.from_pos, move.to_pos], {
          renderer: this.renderer, color: COLOR.migration, weight: 2,
          opacity: fadeFrom !== null && move.at_s < fadeFrom ? FADED : 1
        }).bindTooltip(text(vv.name + ' migrated' +
                            (move.from ? ': ' + move.from + ' → ' + move.to : '')))
          .addTo(L_.migrations);
      }
      if (open + done > before || path.length > 1 || paths.old.length > 1 || moves) shown += 1;
    }
    this._drawVehicles();
    var el = this.element;
    el.dataset.seq = String(this.seq);
    el.dataset.frames = String(this.frames);
    el.dataset.tasksOpen = String(open);
    el.dataset.tasksDone = String(done);
    el.dataset.tasksRefused = String(refused);
    el.dataset.vvs = String(count);
    el.dataset.vvsShown = String(shown);
    this._messageState();
    if (this.options.onDraw) this.options.onDraw(this);
  };

  CPCCMap.prototype._drawVehicles = function () {
    var ids = Object.keys(this.vehicles);
    var labels = ids.length <= LABELS_UP_TO;
    var live = {};
    var kinds = {};
    for (var i = 0; i < ids.length; i++) {
      var v = this.vehicles[ids[i]];
      var kind = kindOf(v);
      live[v.id] = true;
      kinds[kind] = (kinds[kind] || 0) + 1;
      var marker = this.vehicleMarkers[v.id];
      var aboard = (v.vvs || []).map(function (x) { return x.name; }).join(', ');
      var label = (v.name || 'vehicle') + depthNote(v) + (aboard ? ' · ' + aboard : '');
      if (marker && marker.options.kind !== kind) { // its kind was changed: drawn anew
        this.layers.vehicles.removeLayer(marker);
        marker = null;
      }
      if (!marker) {
        marker = kindMarker([v.lat, v.lng], kind, {
          renderer: this.renderer, color: '#fff', weight: 1.5,
          fillColor: KIND_COLOR[kind], fillOpacity: 1
        }).addTo(this.layers.vehicles);
        marker.bindTooltip(text(label), { permanent: labels, direction: 'right',
                                          offset: [KIND_RADIUS + 1, 0],
                                          className: 'vehicle-label' });
        this.vehicleMarkers[v.id] = marker;
      } else {
        marker.setLatLng([v.lat, v.lng]);
        if (this.vehicleLabels[v.id] !== label) marker.setTooltipContent(text(label));
      }
      this.vehicleLabels[v.id] = label;
      if (v.route && v.route.length > 1) {
        L.polyline(v.route, {
          renderer: this.renderer, color: COLOR.route, weight: 2, opacity: 0.8
        }).addTo(this.layers.routes);
      }
    }
    for (var id in this.vehicleMarkers) {
      if (!live[id]) {
        this.layers.vehicles.removeLayer(this.vehicleMarkers[id]);
        delete this.vehicleMarkers[id];
        delete this.vehicleLabels[id];
      }
    }
    this.element.dataset.vehicles = String(ids.length);
    this.element.dataset.vehicleKinds = KINDS.filter(function (k) { return kinds[k]; })
      .map(function (k) { return k + ':' + kinds[k]; }).join(',');
  };

  /* Live: a socket that reconnects by itself and starts again from a snapshot. */
  CPCCMap.prototype.connect = function (path) {
    var self = this;
    var delay = 500;
    var open = function () {
      var scheme = location.protocol === 'https:' ? 'wss://' : 'ws://';
      var socket = new WebSocket(scheme + location.host + path);
      self.socket = socket;
      socket.onopen = function () { delay = 500; };
      socket.onmessage = function (message) {
        var data = JSON.parse(message.data);
        if (data.type === 'snapshot') {
          self.applySnapshot(data);
          self.element.dataset.connected = 'true';
        } else if (data.type === 'frame') {
          if (data.seq !== self.seq + 1) { // a frame was missed: ask for the whole state
            socket.send(JSON.stringify({ type: 'resync' }));
            return;
          }
          self.applyFrame(data);
        }
      };
      socket.onclose = function (event) {
        self.element.dataset.connected = 'false';
        if (event.code === 4403 || event.code === 4404) {
          self.element.dataset.refused = String(event.code);
          return;
        }
        setTimeout(open, delay);
        delay = Math.min(delay * 2, 10000);
      };
    };
    open();
  };

  /* Replay: the mission as it was at time t (seconds on the platform clock). */
  CPCCMap.prototype.setTime = function (t) {
    this.time = t;
    this._changed();
  };

  CPCCMap.text = text; // for the other maps' tooltips
  // The vehicles' symbols, for the other maps (the admin's fleet overview).
  CPCCMap.KINDS = KINDS;
  CPCCMap.kindMarker = kindMarker;
  CPCCMap.kindOf = kindOf;
  CPCCMap.depthNote = depthNote;
  window.CPCCMap = CPCCMap;
})();
