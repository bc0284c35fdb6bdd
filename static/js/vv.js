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

  // The page's state of a VV that has not ended (status, where it is, what it waits for, its
  // task counts, the actions offered) is rendered whole from one read of the API's VV
  // (GET /api/v1/vvs/<id>/), never piece by piece from different moments: read again every
  // POLL_MS, and at once when the live map shows a change (another status or task count).
  var POLL_MS = 5000;
  var ENDED_RELOAD_MS = 1500;  // the note that it has ended shows this long before the reload

  function PageState(box) {
    this.api = box.dataset.api;
    this.box = box;
    this.staff = box.dataset.staff === 'true';
    this.shown = { status: badgeStatus(), tasks_open: counter('vv-tasks-open'), tasks_done: counter('vv-tasks-done') };
    this.timer = null;
    this.reading = false;
    this.again = false;
    this.hostKind = null;  // the live map's word on where it is (staff see the host's name)
  }

  function badgeStatus() {
    var badge = document.getElementById('vv-status');
    return badge ? badge.className.replace(/.*status-(\w+).*/, '$1') : '';
  }

  function counter(id) {
    var el = document.getElementById(id);
    return el ? Number(el.textContent) : null;
  }

  PageState.prototype.differs = function (vv) {
    return vv.status !== this.shown.status || vv.tasks_open !== this.shown.tasks_open ||
      vv.tasks_done !== this.shown.tasks_done;
  };

  // Read the VV now (once at a time: a change seen meanwhile reads it again after).
  PageState.prototype.look = function () {
    var self = this;
    if (this.reading) { this.again = true; return; }
    clearTimeout(this.timer);
    this.reading = true;
    fetch(this.api, { credentials: 'same-origin', headers: { Accept: 'application/json' } })
      .then(function (response) {
        if (!response.ok) throw new Error(String(response.status));
        return response.json();
      })
      .then(function (vv) {
        self.render(vv);
        self.next(ENDED[vv.status] ? null : POLL_MS);
      })
      .catch(function () { self.next(POLL_MS * 3); });
  };

  PageState.prototype.next = function (ms) {
    var self = this;
    this.reading = false;
    if (this.again) { this.again = false; this.look(); return; }
    if (ms !== null) this.timer = setTimeout(function () { self.look(); }, ms);
  };

  PageState.prototype.render = function (vv) {
    this.shown = { status: vv.status, tasks_open: vv.tasks_open, tasks_done: vv.tasks_done };
    var badge = document.getElementById('vv-status');
    badge.className = 'badge status-' + vv.status;
    badge.textContent = LABELS[vv.status] || vv.status;
    var where = document.getElementById('vv-where');
    if (where) where.textContent = this.where(vv);
    var open = document.getElementById('vv-tasks-open');
    var done = document.getElementById('vv-tasks-done');
    if (open) open.textContent = String(vv.tasks_open);
    if (done) done.textContent = String(vv.tasks_done);
    var w = ENDED[vv.status] ? null : vv.waiting;
    this.box.hidden = !w;
    this.box.dataset.reason = w ? w.reason : '';
    if (w) {
      document.getElementById('vv-waiting-label').textContent = (w.reason === 'flying' ? 'On its way' : 'Waiting') + ':';
      document.getElementById('vv-waiting-message').textContent = w.message;
    }
    // Edit while queued, cancel until it ends.
    document.querySelectorAll('.head-actions a[href$="/edit/"]').forEach(function (a) {
      a.hidden = vv.status !== 'queued';
    });
    if (ENDED[vv.status]) {
      // Ended: the page of an ended VV (its error, results and replay) replaces this one.
      document.getElementById('vv-ended-note').hidden = false;
      document.querySelectorAll('.head-actions form[action$="/cancel/"]')
        .forEach(function (action) { action.hidden = true; });
      setTimeout(function () { window.location.reload(); }, ENDED_RELOAD_MS);
    }
  };

  // Where the VV is, as the page's server says it (missions.views.where).
  PageState.prototype.where = function (vv) {
    if (this.staff && vv.host) {
      var kind = this.hostKind || (vv.host === 'vehicle' ? 'rv' : 'gs');
      return vv.host + (kind === 'rv' ? ' (vehicle)' : ' (ground station)');
    }
    if (vv.host === 'vehicle') return 'in flight';
    if (vv.host === 'ground station') return 'at a ground station';
    if (vv.status === 'queued') return 'queued';
    return '—';
  };

  function live(el, map, state) {
    var id = el.dataset.vv;
    var status = document.getElementById('vv-map-status');
    var seen = '';
    map.options.onDraw = function () {
      status.textContent = (el.dataset.connected === 'true' ? 'live' : 'reconnecting…') + ' · ' +
        el.dataset.tasksOpen + ' open, ' + el.dataset.tasksDone + ' done';
      var vv = map.vvs[id];
      if (!vv || !vv.status || !state) return;
      state.hostKind = vv.host_kind || state.hostKind;
      var now = { status: vv.status, tasks_open: Number(el.dataset.tasksOpen), tasks_done: Number(el.dataset.tasksDone) };
      var key = JSON.stringify(now);
      if (key !== seen && state.differs(now)) state.look();  // once for each change the map shows
      seen = key;
    };
    map.connect(el.dataset.socket);
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

  // A moment (epoch milliseconds) as a UTC clock time, "13:04:05" (or "13:04" without
  // seconds), with its date in front ("2026-11-27 13:04:05") when asked.
  function utcClock(ms, withDate, withoutSeconds) {
    var iso = new Date(ms).toISOString();
    return (withDate ? iso.slice(0, 10) + ' ' : '') + iso.slice(11, withoutSeconds ? 16 : 19);
  }

  // The time axis shows at least this many seconds: one reading, or a few a second apart,
  // sit in the middle of a minute with ticks a few seconds apart.
  var MIN_SPAN_S = 60;

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
    // The axis: the readings' span with a margin (at least MIN_SPAN_S), cut at clock-round
    // ticks; the step, and so the labels' unit (seconds or minutes), chosen from that span.
    var from = (first - origin) / 1000, to = (last - origin) / 1000;
    var margin = Math.max((to - from) * 0.05, (MIN_SPAN_S - (to - from)) / 2);
    var step = clockStep(to - from + 2 * margin);
    var axisMin = Math.floor((from - margin) / step) * step;
    var axisMax = Math.ceil((to + margin) / step) * step;
    var seconds = step < 60;  // else every tick is on a whole minute: "13:05"
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
              min: axisMin,
              max: axisMax,
              title: { display: true, text: 'time (UTC)' },
              ticks: {
                stepSize: step,
                maxRotation: 0,
                callback: function (value) {
                  return utcClock(origin + value * 1000, spansDays, !seconds);
                }
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
    var box = document.getElementById('vv-waiting');
    var state = box && box.dataset.api ? new PageState(box) : null;
    if (state) state.next(POLL_MS);
    charts();
    var el = document.getElementById('vv-map');
    if (!el || !window.CPCCMap) return;
    var map = new window.CPCCMap(el, {
      tiles: el.dataset.tiles || '', fade: false,
      // An ended VV's page holds the points no vehicle could serve in view (why it failed).
      fitRefused: el.dataset.mode === 'replay'
    });
    window.cpccMap = map;
    if (el.dataset.mode === 'replay') replay(el, map);
    else live(el, map, state);
  });
})();
