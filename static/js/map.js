/* The live map (missions/consumers.py sends what it shows; missions/events.py the shapes).
 *
 * CPCCMap draws, on a Leaflet map with its canvas renderer: operation areas, ground stations,
 * vehicles (with their name and the VVs aboard for staff), planned vehicle routes (gray), the
 * paths of VVs while carried (green), the paths VVs intend to take (light blue), done tasks
 * (red dots), open tasks (blue dots) and migrations (red lines). It is fed snapshots and
 * frames, live from the socket (connect) or from a mission's history (replay).
 *
 * Its state is on the map element for whoever looks (tests, the page): data-seq (last frame),
 * data-connected, data-vehicles, data-tasks-open, data-tasks-done, data-vvs, data-frames.
 *
 * Names (VVs, vehicles, areas, ground stations) are the customers' and operators' words, never
 * markup: every tooltip is a DOM node whose text is set by text() (Leaflet would take a string
 * as HTML).
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
    migration: '#d62828'
  };
  var LABELS_UP_TO = 60; // permanent vehicle labels only while they stay readable

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
    this.map = L.map(element, { preferCanvas: true, renderer: this.renderer, zoomSnap: 0.25 });
    if (options.tiles) {
      L.tileLayer(options.tiles, { maxZoom: 20, attribution: options.attribution || '' })
        .addTo(this.map);
    }
    this.layers = {};
    var order = ['areas', 'stations', 'routes', 'intended', 'carried', 'migrations', 'tasks',
                 'vehicles'];
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
    this.time = null;     // replay: show the mission as it was at this time (seconds)
    this._fitted = false;
    this._dirty = false;
    this.map.setView([0, 0], 2);
  }

  CPCCMap.prototype.applySnapshot = function (snapshot) {
    this.staff = !!snapshot.staff;
    this.seq = snapshot.seq || 0;
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
    for (var i = 0; i < events.length; i++) this._event(events[i]);
    this._vehicles(frame.vehicles || [], frame.gone || []);
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
      bounds.extend([gs.lat, gs.lng]);
    }
    if (!this._fitted) {
      for (var id in this.vvs) {
        var tasks = this.vvs[id].tasks;
        for (var t in tasks) bounds.extend([tasks[t].lat, tasks[t].lng]);
      }
      if (bounds.isValid()) {
        this.map.fitBounds(bounds.pad(0.08));
        this._fitted = true;
      }
    }
  };

  // Only what had happened by the replay's time (everything when live).
  CPCCMap.prototype._seen = function (t) {
    return this.time === null || (t !== null && t !== undefined && t <= this.time);
  };

  CPCCMap.prototype._draw = function () {
    var L_ = this.layers;
    L_.tasks.clearLayers(); L_.carried.clearLayers(); L_.intended.clearLayers();
    L_.migrations.clearLayers(); L_.routes.clearLayers();
    var open = 0, done = 0, count = 0;
    for (var id in this.vvs) {
      var vv = this.vvs[id];
      count += 1;
      var path = [];
      for (var p = 0; p < vv.track.length; p++) {
        if (this._seen(vv.track[p][0])) path.push([vv.track[p][1], vv.track[p][2]]);
      }
      if (path.length > 1) {
        L.polyline(path, { renderer: this.renderer, color: COLOR.carried, weight: 3 })
          .bindTooltip(text(vv.name)).addTo(L_.carried);
      }
      var pending = [];
      for (var tid in vv.tasks) {
        var task = vv.tasks[tid];
        var isDone = task.status === 'done' && this._seen(task.done_s);
        var isOpen = this.time === null ? task.status === 'open'
          : this._seen(task.requested_s) && !isDone && task.status !== 'rejected'
            && task.status !== 'cancelled';
        if (!isDone && !isOpen) continue;
        if (isDone) done += 1; else { open += 1; pending.push(task); }
        L.circleMarker([task.lat, task.lng], {
          renderer: this.renderer, radius: 4, stroke: false, fillOpacity: 0.9,
          fillColor: isDone ? COLOR.done : COLOR.open
        }).bindTooltip(text(vv.name + ': task ' + task.q + (task.index ? '.' + task.index : '') +
                            (isDone ? ' (done)' : ' (open)')))
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
        L.polyline([move.from_pos, move.to_pos], {
          renderer: this.renderer, color: COLOR.migration, weight: 2
        }).bindTooltip(text(vv.name + ' migrated' +
                            (move.from ? ': ' + move.from + ' → ' + move.to : '')))
          .addTo(L_.migrations);
      }
    }
    this._drawVehicles();
    var el = this.element;
    el.dataset.seq = String(this.seq);
    el.dataset.frames = String(this.frames);
    el.dataset.tasksOpen = String(open);
    el.dataset.tasksDone = String(done);
    el.dataset.vvs = String(count);
    if (this.options.onDraw) this.options.onDraw(this);
  };

  CPCCMap.prototype._drawVehicles = function () {
    var ids = Object.keys(this.vehicles);
    var labels = ids.length <= LABELS_UP_TO;
    var live = {};
    for (var i = 0; i < ids.length; i++) {
      var v = this.vehicles[ids[i]];
      live[v.id] = true;
      var marker = this.vehicleMarkers[v.id];
      var aboard = (v.vvs || []).map(function (x) { return x.name; }).join(', ');
      var label = (v.name || 'vehicle') + (aboard ? ' · ' + aboard : '');
      if (!marker) {
        marker = L.circleMarker([v.lat, v.lng], {
          renderer: this.renderer, radius: 7, color: '#fff', weight: 2,
          fillColor: COLOR.vehicle, fillOpacity: 1
        }).addTo(this.layers.vehicles);
        marker.bindTooltip(text(label), { permanent: labels, direction: 'right', offset: [8, 0],
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

  window.CPCCMap = CPCCMap;
})();
