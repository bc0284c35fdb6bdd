/* The dashboard (templates/missions/home.html) keeps itself up to date: it listens on the live
 * map's socket (/ws/map/, missions/consumers.py) and, when a frame says that one of the user's
 * VVs or tasks changed, fetches its rows again from the server (/vvs/rows/, the same
 * template), at most about once a second. Without the socket it polls every 10 seconds.
 *
 * State for whoever looks (tests): data-live ("true", "polling", "false") and data-refreshes
 * on #dashboard. */
(function () {
  'use strict';

  var MIN_INTERVAL_MS = 1000;
  var POLL_MS = 10000;

  document.addEventListener('DOMContentLoaded', function () {
    var root = document.getElementById('dashboard');
    if (!root) return;
    var body = document.getElementById('dashboard-body');
    var state = document.getElementById('live-state');
    var rowsUrl = root.dataset.rowsUrl;
    var last = 0, timer = null, loading = false, again = false, poller = null;

    function show(mode, text) {
      root.dataset.live = mode;
      state.textContent = text;
    }

    function statuses() {
      var seen = {};
      body.querySelectorAll('tr[data-vv]').forEach(function (row) {
        seen[row.dataset.vv] = row.dataset.status + '|' + row.querySelector('.tasks-done').textContent +
          '|' + row.querySelector('.tasks-open').textContent;
      });
      return seen;
    }

    function refresh() {
      timer = null;
      if (loading) { again = true; return; }
      loading = true;
      last = Date.now();
      var before = statuses();
      fetch(rowsUrl, { credentials: 'same-origin', headers: { 'X-Requested-With': 'fetch' } })
        .then(function (response) {
          if (response.redirected || !response.ok) throw new Error('rows: ' + response.status);
          return response.text();
        })
        .then(function (html) {
          // The server's rendering of the rows (templates/missions/_dashboard_rows.html, every
          // name escaped by the template), parsed in a document of its own (inert: nothing in
          // it loads or runs), then moved here.
          var rows = new DOMParser().parseFromString(html, 'text/html').body;
          body.replaceChildren.apply(body, Array.prototype.slice.call(rows.childNodes));
          var after = statuses();
          for (var id in after) {
            if (before[id] !== after[id]) {
              var row = body.querySelector('tr[data-vv="' + id + '"]');
              if (row) row.classList.add('updated');
            }
          }
          root.dataset.refreshes = String(Number(root.dataset.refreshes || 0) + 1);
        })
        .catch(function () { /* the next change or poll tries again */ })
        .then(function () {
          loading = false;
          if (again) { again = false; schedule(); }
        });
    }

    function schedule() {
      if (timer !== null) return;
      var wait = Math.max(150, MIN_INTERVAL_MS - (Date.now() - last));
      timer = setTimeout(refresh, wait);
    }

    function poll(on) {
      if (on && poller === null) poller = setInterval(schedule, POLL_MS);
      if (!on && poller !== null) { clearInterval(poller); poller = null; }
    }

    var delay = 500, snapshots = 0;
    function connect() {
      var scheme = location.protocol === 'https:' ? 'wss://' : 'ws://';
      var socket;
      try {
        socket = new WebSocket(scheme + location.host + root.dataset.socket);
      } catch (e) {
        show('polling', 'updates every 10 s');
        poll(true);
        return;
      }
      socket.onmessage = function (message) {
        var data = JSON.parse(message.data);
        if (data.type === 'snapshot') {
          delay = 500;
          show('true', 'live');
          poll(false);
          // The first snapshot comes right after the page was made; a later one (after a
          // reconnect) may follow changes this page missed.
          if (snapshots++ > 0) schedule();
        } else if (data.type === 'frame') {
          var events = data.events || [];
          for (var i = 0; i < events.length; i++) {
            if (events[i].kind === 'vv' || events[i].kind === 'task') { schedule(); break; }
          }
        }
      };
      socket.onclose = function (event) {
        if (event.code === 4403) { show('false', 'not live'); return; }
        show('polling', 'reconnecting…');
        poll(true);
        setTimeout(connect, delay);
        delay = Math.min(delay * 2, 15000);
      };
    }
    connect();
  });
})();
