/* The fleet overview (fleet/admin.py, VehicleAdmin.overview_view), live: the map of the fleet
   (every RV that is not removed, with its operation area, its position, its name and the VVs
   aboard; the ground stations) and the table of its RVs, both first as the server rendered
   them (the page's JSON, #fleet-overview-data, and the table), then kept up to date by what
   the RVs' workers report on the live map's socket (/ws/map/, missions/consumers.py; staff
   see each vehicle's whole state, vvm_worker/hosts.py HostedRV.beacon): status and why,
   what it is doing, its next task, altitude, speed, battery, link, VVs aboard and position.
   A vehicle whose worker stops reporting is marked so.

   Each RV's action buttons ask first, in a dialog (#fleet-confirm), and post their form once
   the operator confirms (confirmed=yes); without this script the server asks on a page.

   State for tests, on the map's element: data-state ("ready"), data-vehicles (RV markers
   drawn), data-areas, data-stations; on #fleet-live: data-live ("true" while the socket is
   up), data-frames (frames applied) and data-seq; on each row: data-status, data-updates (how
   many reports changed it). Names are operators' words, never markup: text only.

   Each RV is drawn with its kind's symbol (static/js/map.js, CPCCMap.kindMarker: a copter, a
   rover, a boat, a submarine, whose label says its depth), filled with its status's colour;
   data-vehicle-kinds on the map's element counts them per kind ("aerial:2,ground:1"). */
(function () {
  'use strict';

  var M = window.CPCCAdminMap;

  function label(v) {
    var count = v.vvs_aboard === undefined ? (v.vvs || []).length : v.vvs_aboard;
    return v.name + CPCCMap.depthNote(v) + ' · ' + (count === 1 ? '1 VV' : count + ' VVs');
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

  /* A vehicle's health in a few words, as fleet/admin.py _health_text says it. */
  function healthText(h) {
    var parts = [];
    if (!h) return '';
    if (h.worker) parts.push('worker ' + h.worker);
    if (h.link) parts.push('link ' + h.link);
    if (h.armed !== null && h.armed !== undefined) parts.push(h.armed ? 'armed' : 'disarmed');
    if (h.mode) parts.push(String(h.mode));
    if (h.fence) parts.push('fence ' + h.fence);
    if (h.took_over) parts.push('taken over in ' + h.took_over);
    return parts.join(' · ');
  }

  function quiet(value) {
    var span = document.createElement('span');
    span.className = 'cpcc-quiet';
    span.textContent = value;
    return span;
  }

  function fixed(value, digits) {
    return typeof value === 'number' && isFinite(value) ? value.toFixed(digits) : null;
  }

  /* The map: the server's data, then the vehicles' reports. */
  function FleetMap(element, data) {
    this.element = element;
    this.map = M.createMap(element, element.dataset.tiles, { preferCanvas: true });
    var flying = data.vehicles.filter(function (v) { return v.status !== 'removed'; });
    var areas = M.addAreas(this.map, flying);
    var stations = M.addStations(this.map, data.stations, true);
    this.vehicles = L.featureGroup();
    this.markers = {}; // vehicle name -> marker
    this.labels = {};
    var self = this;
    flying.forEach(function (v) { self.show(v); });
    this.vehicles.addTo(this.map);
    M.fit(this.map, [areas, stations, this.vehicles]);
    element.dataset.areas = String(areas.getLayers().length);
    element.dataset.stations = String(stations.getLayers().length);
    this.count();
    element.dataset.state = 'ready';
    window.CPCCFleetMap = this.map;
  }

  FleetMap.prototype.show = function (v) {
    var marker = this.markers[v.name];
    var text = label(v);
    if (marker && marker.options.kind !== CPCCMap.kindOf(v)) { // its kind changed: drawn anew
      this.vehicles.removeLayer(marker);
      marker = null;
    }
    if (!marker) {
      marker = CPCCMap.kindMarker([v.lat, v.lng], CPCCMap.kindOf(v), {
        color: '#ffffff', weight: 1.5, fillColor: M.statusColor(v.status), fillOpacity: 1
      });
      marker.bindTooltip(M.text(text), {
        permanent: true, direction: 'right', offset: [11, 0], className: 'cpcc-map-label'
      });
      if (v.url) marker.bindPopup(popup(v));
      marker.addTo(this.vehicles);
      this.markers[v.name] = marker;
    } else {
      marker.setLatLng([v.lat, v.lng]);
      marker.setStyle({ fillColor: M.statusColor(v.status) });
      if (this.labels[v.name] !== text) marker.setTooltipContent(M.text(text));
    }
    this.labels[v.name] = text;
  };

  FleetMap.prototype.count = function () {
    var kinds = {};
    this.vehicles.getLayers().forEach(function (marker) {
      kinds[marker.options.kind] = (kinds[marker.options.kind] || 0) + 1;
    });
    this.element.dataset.vehicles = String(this.vehicles.getLayers().length);
    this.element.dataset.vehicleKinds = CPCCMap.KINDS.filter(function (k) { return kinds[k]; })
      .map(function (k) { return k + ':' + kinds[k]; }).join(',');
  };

  /* One row of the table, updated from a vehicle's report. */
  function Row(tr, statuses) {
    this.tr = tr;
    this.statuses = statuses;
    this.id = tr.querySelector('[data-vehicle-id]').dataset.vehicleId;
    this.name = tr.dataset.vehicle;
    this.kind = this.cell('kind').dataset.kind; // until its worker's reports say it
    var next = tr.nextElementSibling;
    this.actions = next && next.dataset.actionsFor === this.name ? next : null;
    this.updates = 0;
  }

  Row.prototype.cell = function (name) {
    return this.tr.querySelector('[data-cell="' + name + '"]');
  };

  /* A value with a quiet line under it (why, where). */
  function withNote(value, note) {
    var line = document.createElement('div');
    line.className = 'cpcc-quiet';
    line.textContent = note;
    return [document.createTextNode(value), line];
  }

  Row.prototype.set = function (name, value) {
    var cell = this.cell(name);
    if (!cell) return;
    if (typeof value === 'string') cell.textContent = value;
    else cell.replaceChildren.apply(cell, value);
  };

  Row.prototype.apply = function (v) {
    var status = v.status || this.tr.dataset.status;
    this.tr.dataset.status = status;
    var pill = this.tr.querySelector('[data-status-label]');
    pill.textContent = this.statuses[status] || status;
    pill.className = 'cpcc-pill cpcc-pill-' + status;
    var reason = this.tr.querySelector('[data-status-reason]');
    if (typeof v.status_reason === 'string' && reason.dataset.statusReason !== v.status_reason) {
      reason.dataset.statusReason = v.status_reason;
      reason.textContent = v.status_reason;
    }
    this.command(v.command);
    var doing = v.activity && v.activity !== v.phase ? v.activity + ' · ' + v.phase : v.phase;
    this.set('doing', String(doing));
    this.set('next', this.next(v));
    var alt = fixed(v.alt, 0);
    this.set('altitude', alt === null ? [quiet('n/a')] : alt + ' m');
    var speed = fixed(v.speed_mps, 1);
    this.set('speed', speed === null ? [quiet('n/a')] : speed + ' m/s');
    this.battery(v);
    var health = healthText(v.health) || (v.link ? 'link ' + v.link : '');
    this.set('link', health ? health : [quiet('not reported')]);
    var aboard = (v.vvs || []).length;
    var vvs = this.cell('vvs');
    vvs.textContent = String(aboard);
    vvs.dataset.vvsAboard = String(aboard);
    this.set('position', fixed(v.lat, 5) + ', ' + fixed(v.lng, 5));
    this.tr.dataset.lease = 'fresh';
    var lease = document.createElement('span');
    lease.className = 'cpcc-pill cpcc-pill-fresh';
    lease.textContent = 'fresh, live';
    this.set('lease', [lease]);
    if (this.actions) {
      this.actions.querySelectorAll('button[data-never]').forEach(function (button) {
        button.disabled = button.dataset.never.split(' ').indexOf(status) >= 0;
      });
    }
    this.updates += 1;
    this.tr.dataset.updates = String(this.updates);
  };

  /* The operator's last command: taken once the worker reports it obeyed that one. */
  Row.prototype.command = function (obeyed) {
    var note = this.tr.querySelector('[data-command]');
    if (!note || !obeyed || note.dataset.taken === 'true' || obeyed.asked !== note.dataset.asked) {
      return;
    }
    note.dataset.taken = 'true';
    // As the page the server renders says it (the time in UTC, the site's TIME_ZONE): when
    // this page heard of it, within one report of when the worker took it.
    note.querySelector('[data-command-state]').textContent =
      'taken by its worker ' + new Date().toISOString().slice(11, 19);
  };

  Row.prototype.next = function (v) {
    var task = v.next_task;
    if (!task) return [quiet(v.activity === 'flying to a task' ? 'a task' : 'none')];
    var owner = (v.vvs || []).filter(function (vv) { return vv.id === task.vv; })[0];
    return withNote((owner ? owner.name : 'a VV') + ', about ' + task.eta_s + ' s away',
      fixed(task.lat, 5) + ', ' + fixed(task.lng, 5) + ', ' + fixed(task.alt, 0) + ' m');
  };

  Row.prototype.battery = function (v) {
    if (typeof v.battery !== 'number') {
      this.set('battery', withNote('n/a', v.battery_why || 'not reported'));
      return;
    }
    var percent = Math.round(v.battery * 100);
    var meter = document.createElement('meter');
    meter.className = 'cpcc-battery';
    meter.min = 0; meter.max = 100; meter.low = 20; meter.high = 20; meter.optimum = 100;
    meter.value = percent;
    meter.setAttribute('aria-hidden', 'true');
    this.set('battery', [meter, document.createTextNode(percent + ' %')]);
  };

  /* A vehicle whose worker stopped reporting (the socket's "gone"). */
  Row.prototype.silent = function () {
    this.set('link', [quiet('no report from its worker')]);
    this.set('speed', [quiet('n/a')]);
    this.set('next', [quiet('unknown')]);
    this.updates += 1;
    this.tr.dataset.updates = String(this.updates);
  };

  function FleetPage(mapElement, data) {
    this.map = new FleetMap(mapElement, data);
    this.status = document.getElementById('fleet-live');
    this.rows = {};
    this.seq = 0;
    this.frames = 0;
    var self = this;
    document.querySelectorAll('#fleet-vehicles tr[data-vehicle]').forEach(function (tr) {
      var row = new Row(tr, data.statuses || {});
      self.rows[row.id] = row;
    });
  }

  FleetPage.prototype.vehicles = function (states, gone) {
    var self = this;
    states.forEach(function (v) {
      var row = self.rows[String(v.id)];
      if (!row) return; // added since the page was loaded: shown when it is loaded again
      row.apply(v);
      if (v.status !== 'removed') {
        self.map.show({
          name: row.name, kind: v.kind || row.kind, lat: v.lat, lng: v.lng, alt: v.alt,
          status: v.status, vvs: v.vvs
        });
      }
    });
    (gone || []).forEach(function (id) {
      var row = self.rows[String(id)];
      if (row) row.silent();
    });
    this.map.count();
  };

  FleetPage.prototype.live = function (on) {
    this.status.dataset.live = on ? 'true' : 'false';
    this.status.dataset.frames = String(this.frames);
    this.status.dataset.seq = String(this.seq);
    var now = new Date().toISOString().slice(11, 19);
    this.status.textContent = on
      ? 'Live: the vehicles\u2019 reports as they come (last ' + now + ' UTC).'
      : 'Reconnecting to the vehicles\u2019 reports\u2026';
  };

  /* The live map's socket, as static/js/map.js uses it: a snapshot first, then numbered
     frames; a missed frame asks for the whole state again; a lost socket reconnects. */
  FleetPage.prototype.connect = function (path) {
    var self = this;
    var delay = 500;
    var open = function () {
      var scheme = location.protocol === 'https:' ? 'wss://' : 'ws://';
      var socket = new WebSocket(scheme + location.host + path);
      socket.onopen = function () { delay = 500; };
      socket.onmessage = function (message) {
        var data = JSON.parse(message.data);
        if (data.type === 'snapshot') {
          self.seq = data.seq || 0;
          self.vehicles(data.vehicles || [], []);
        } else if (data.type === 'frame') {
          if (data.seq !== self.seq + 1) {
            socket.send(JSON.stringify({ type: 'resync' }));
            return;
          }
          self.seq = data.seq;
          self.frames += 1;
          self.vehicles(data.vehicles || [], data.gone || []);
        } else {
          return;
        }
        self.live(true);
      };
      socket.onclose = function (event) {
        self.live(false);
        if (event.code === 4403 || event.code === 4404) return;
        setTimeout(open, delay);
        delay = Math.min(delay * 2, 10000);
      };
    };
    open();
  };

  /* Every action asks first: the dialog says what it does; "yes" posts the row's form. */
  function confirmActions() {
    var dialog = document.getElementById('fleet-confirm');
    if (!dialog || typeof dialog.showModal !== 'function') return; // the server asks instead
    var pending = null;
    document.querySelectorAll('form[data-vehicle-actions]').forEach(function (form) {
      form.addEventListener('submit', function (event) {
        var button = event.submitter;
        if (!button || !button.dataset.confirm) return;
        event.preventDefault();
        pending = { form: form, button: button };
        var name = form.closest('tr').dataset.actionsFor;
        document.getElementById('fleet-confirm-title').textContent =
          button.textContent.trim() + ': ' + name;
        document.getElementById('fleet-confirm-text').textContent = button.dataset.confirm;
        document.getElementById('fleet-confirm-yes').textContent = button.textContent.trim();
        dialog.returnValue = '';
        dialog.showModal();
      });
    });
    dialog.addEventListener('close', function () {
      var chosen = pending;
      pending = null;
      if (!chosen || dialog.returnValue !== 'yes') return;
      var form = chosen.form;
      form.querySelectorAll('input[data-chosen]').forEach(function (input) { input.remove(); });
      [['act', chosen.button.value], ['confirmed', 'yes']].forEach(function (pair) {
        var input = document.createElement('input');
        input.type = 'hidden';
        input.name = pair[0];
        input.value = pair[1];
        input.dataset.chosen = 'true';
        form.append(input);
      });
      form.submit();
    });
  }

  document.addEventListener('DOMContentLoaded', function () {
    var element = document.querySelector('[data-fleet-map]');
    if (!element) return;
    var data = JSON.parse(document.getElementById(element.dataset.context).textContent);
    var page = new FleetPage(element, data);
    window.CPCCFleetPage = page;
    confirmActions();
    page.connect(element.dataset.socket || '/ws/map/');
  });
})();
