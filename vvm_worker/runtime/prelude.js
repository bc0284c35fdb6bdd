// The VVM-API inside a virtual vehicle's V8 isolate (DESIGN.md section 2).
//
// One isolate serves one VV for as long as the VV stays on a host (a warm context). It is
// set up once: the built-ins are frozen, so nothing a program does to them can outlive the run
// that did it, and everything that could observe the host (timers, console, WebAssembly,
// Atomics, WeakRef, Intl, Temporal, code generation from strings) is removed or disabled.
//
// Every step re-runs the program from its first line (deterministic replay): each VVM-API call
// that needs the outside world is answered from the journal; the first one without an answer
// becomes the pending request and the step ends: the call throws SUSPEND, and every later
// VVM-API call throws it again. The program is instrumented when it is loaded so that its own
// `catch` clauses rethrow SUSPEND and its `finally` clauses are skipped while suspended.
//
// Effects (storage writes, log lines) are numbered from the program's start; only those at or
// after `effectsApplied` are reported to the host, so replaying never applies an effect twice.
// Storage itself is rebuilt by the replay, which makes `load` deterministic.
//
// The host talks to this file only through `__cpcc_host`, whose functions refuse to run while
// the program runs, and reads results as strings made with functions captured here first.
(function (hostKey) {
  'use strict';

  const global = globalThis;
  const jsonStringify = JSON.stringify;
  const jsonParse = JSON.parse;
  const defineProperty = Object.defineProperty;
  const getOwnPropertyDescriptor = Object.getOwnPropertyDescriptor;
  const getPrototypeOf = Object.getPrototypeOf;
  const freeze = Object.freeze;
  const ownKeys = Reflect.ownKeys;
  const reflectApply = Reflect.apply;
  const reflectDeleteProperty = Reflect.deleteProperty;
  const isArray = Array.isArray;
  const numberIsFinite = Number.isFinite;
  const mathImul = Math.imul;
  const stringOf = String;
  const RealDate = Date;
  const RealError = Error;
  const RealRegExp = RegExp;
  const RealMap = Map;
  const RealSet = Set;
  const regExpTest = RegExp.prototype.test;
  const arraySort = Array.prototype.sort;
  const arraySlice = Array.prototype.slice;
  const arrayJoin = Array.prototype.join;
  const mapGet = Map.prototype.get;
  const mapSet = Map.prototype.set;
  const mapHas = Map.prototype.has;
  const mapDelete = Map.prototype.delete;
  const mapKeys = Map.prototype.keys;
  const setHas = Set.prototype.has;
  const setAdd = Set.prototype.add;
  const stringSlice = String.prototype.slice;

  function push(list, item) {
    list[list.length] = item;
  }

  // --- removing what could observe the host --------------------------------------------------
  // mini-racer declares its timers with `var`: they cannot be deleted, only emptied.
  global.setTimeout = undefined;
  global.clearTimeout = undefined;
  global.__timer_manager = undefined;
  for (const name of ['console', 'WebAssembly', 'Atomics', 'SharedArrayBuffer', 'WeakRef',
    'FinalizationRegistry', 'Intl', 'Temporal']) {
    delete global[name];
  }

  // --- the state of the current run ------------------------------------------------------------
  let run = null; // set by step(); the API objects of a run close over their own state
  let running = false;

  // --- determinism: seeded Math.random and a logical clock ------------------------------------
  function random() {
    return run === null ? 0 : run.random();
  }
  defineProperty(Math, 'random', { value: random, writable: false, configurable: false });

  function clockMs() {
    return run === null ? 0 : run.clockMs;
  }
  function VVDate(...args) {
    if (new.target === undefined) return new RealDate(clockMs()).toString();
    if (args.length === 0) return new RealDate(clockMs());
    return new RealDate(...args);
  }
  VVDate.prototype = RealDate.prototype;
  VVDate.now = function now() { return clockMs(); };
  VVDate.parse = RealDate.parse;
  VVDate.UTC = RealDate.UTC;
  defineProperty(RealDate.prototype, 'constructor', { value: VVDate, writable: true, configurable: true });
  defineProperty(global, 'Date', { value: VVDate, writable: true, configurable: true });

  // --- freezing the built-ins ---------------------------------------------------------------------
  // Assigning a property that a frozen prototype also has fails (the "override mistake"), which
  // would break ordinary code such as `this.name = 'MyError'` or `P.prototype.toString = ...`.
  // These properties become accessors whose setter defines the property on the object itself.
  function enableOverride(object, key) {
    const desc = getOwnPropertyDescriptor(object, key);
    if (desc === undefined || !('value' in desc) || !desc.configurable) return;
    const value = desc.value;
    defineProperty(object, key, {
      get: function () { return value; },
      set: function (next) {
        if (this === object) throw new TypeError('the built-in ' + stringOf(key) + ' cannot be changed');
        defineProperty(this, key, { value: next, writable: true, enumerable: true, configurable: true });
      },
      enumerable: desc.enumerable,
      configurable: false,
    });
  }
  for (const key of ownKeys(Object.prototype)) {
    if (key !== '__proto__') enableOverride(Object.prototype, key);
  }
  const errors = [Error, EvalError, RangeError, ReferenceError, SyntaxError, TypeError, URIError, AggregateError];
  for (const E of errors) {
    for (const key of ['name', 'message', 'constructor', 'toString', 'stack']) enableOverride(E.prototype, key);
  }
  for (const key of ownKeys(global)) {
    const desc = getOwnPropertyDescriptor(global, key);
    const value = desc && desc.value;
    if (typeof value === 'function' && value.prototype && typeof value.prototype === 'object') {
      enableOverride(value.prototype, 'constructor');
      enableOverride(value.prototype, 'toString');
    }
  }
  enableOverride(Function.prototype, 'constructor');
  enableOverride(Function.prototype, 'toString');

  // Intrinsics no global property leads to, found through objects made from syntax.
  const hidden = [
    function* () {}, async function () {}, async function* () {}, (function* () {})(),
    (async function* () {})(), [][Symbol.iterator](), new Map()[Symbol.iterator](),
    new Set()[Symbol.iterator](), ''[Symbol.iterator](), /a/[Symbol.matchAll]('a'),
    Object.getPrototypeOf(Int8Array), (function () { return arguments; })(),
  ];

  function harden(roots) {
    const seen = new RealSet();
    const stack = [];
    for (let i = 0; i < roots.length; i++) push(stack, roots[i]);
    while (stack.length > 0) {
      const o = stack.pop();
      if (o === null || (typeof o !== 'object' && typeof o !== 'function')) continue;
      if (reflectApply(setHas, seen, [o]) || o === global) continue;
      reflectApply(setAdd, seen, [o]);
      freeze(o);
      push(stack, getPrototypeOf(o));
      const keys = ownKeys(o);
      for (let i = 0; i < keys.length; i++) {
        const desc = getOwnPropertyDescriptor(o, keys[i]);
        if (desc === undefined) continue;
        if ('value' in desc) push(stack, desc.value);
        else { push(stack, desc.get); push(stack, desc.set); }
      }
    }
  }

  // The global object stays extensible (a sloppy program may create globals while it runs;
  // they are deleted before the next run), but its own properties are fixed.
  const roots = [];
  for (const key of ownKeys(global)) {
    const desc = getOwnPropertyDescriptor(global, key);
    if (desc.configurable || desc.writable) {
      if ('value' in desc) {
        defineProperty(global, key, { value: desc.value, writable: false, enumerable: desc.enumerable, configurable: false });
      } else {
        defineProperty(global, key, { get: desc.get, set: desc.set, enumerable: desc.enumerable, configurable: false });
      }
    }
    if ('value' in desc) push(roots, desc.value);
  }
  for (let i = 0; i < hidden.length; i++) push(roots, hidden[i]);
  harden(roots);

  const RUN_GLOBALS = ['VV', 'TaskRejectedError', 'logInfo', 'getStdOut'];
  let baseline = null; // the global object's own keys once this file has run
  const baselineProto = getPrototypeOf(global);

  // Deletes what the last run added to the global object. False when it cannot, and the
  // context must not be reused.
  function resetGlobals() {
    if (getPrototypeOf(global) !== baselineProto) return false;
    const keys = ownKeys(global);
    for (let i = 0; i < keys.length; i++) {
      if (!reflectApply(setHas, baseline, [keys[i]]) && !reflectDeleteProperty(global, keys[i])) return false;
    }
    return true;
  }

  // --- the context's own data: catalog, journal, program ------------------------------------
  let catalog = [];
  const journal = []; // [{q, k, t, r, i, message, data (JSON text)}]
  let program = null;
  let tainted = false;

  // --- one run of the program -----------------------------------------------------------------
  const SUSPEND = freeze({ cpccSuspend: true });
  const MAX_ALT_M = 20000;
  const MAX_KEY = 128;
  const MAX_LINE = 4000;

  function describe(value) {
    if (typeof value === 'string') return jsonStringify(value);
    if (value === null || typeof value !== 'object') return stringOf(value);
    return isArray(value) ? 'an array' : 'an object';
  }

  function checkNumber(what, value, lo, hi) {
    if (typeof value !== 'number' || !numberIsFinite(value)) {
      throw new RangeError(what + ' must be a finite number, got ' + describe(value));
    }
    if (value < lo || value > hi) {
      throw new RangeError(what + ' ' + value + ' is outside ' + lo + '..' + hi);
    }
    return value;
  }

  class TaskRejectedError extends RealError {
    constructor(message) {
      super(message);
      defineProperty(this, 'name', { value: 'TaskRejectedError', writable: true, configurable: true });
    }
  }
  class VVMError extends RealError {
    constructor(message) {
      super(message);
      defineProperty(this, 'name', { value: 'VVMError', writable: true, configurable: true });
    }
  }

  class LatLngAlt {
    constructor(lat, lng, alt) {
      this.lat = checkNumber('latitude', lat, -90, 90);
      this.lng = checkNumber('longitude', lng, -180, 180);
      this.alt = checkNumber('altitude', alt === undefined ? 0 : alt, 0, MAX_ALT_M);
    }
    getLat() { return this.lat; }
    getLng() { return this.lng; }
    getAlt() { return this.alt; }
    toString() { return '(' + this.lat + ', ' + this.lng + ', ' + this.alt + ' m)'; }
  }
  class LatLng extends LatLngAlt {
    constructor(lat, lng) {
      super(lat, lng, 0);
    }
  }
  harden([TaskRejectedError, VVMError, LatLngAlt, LatLng]);

  function sdcEntry(e) {
    return freeze({
      name: e.name,
      description: e.name,
      kind: e.kind,
      unit: e.unit,
      params: freeze(jsonParse(jsonStringify(e.params || {}))),
    });
  }

  function newRun(input) {
    const state = {
      clockMs: input.startMs,
      random: null,
    };
    const effectsApplied = input.effectsApplied;
    const limits = input.limits;
    let suspended = false;
    let pending = null;
    let fatal = null;
    const effects = [];
    let effectSeq = 0;
    let cursor = 0;
    let requestSeq = 0;
    let tasksRequested = 0;
    let storageChars = 0;
    const storage = new RealMap();
    const sdc = new RealMap();
    for (let i = 0; i < catalog.length; i++) reflectApply(mapSet, sdc, [catalog[i].name, catalog[i]]);

    // sfc32, seeded through splitmix32 from the VV's seed.
    let seedState = input.seed >>> 0;
    function splitmix32() {
      seedState = (seedState + 0x9e3779b9) | 0;
      let z = seedState;
      z = mathImul(z ^ (z >>> 16), 0x85ebca6b);
      z = mathImul(z ^ (z >>> 13), 0xc2b2ae35);
      return (z ^ (z >>> 16)) >>> 0;
    }
    let ra = splitmix32(), rb = splitmix32(), rc = splitmix32(), rd = splitmix32();
    state.random = function () {
      ra >>>= 0; rb >>>= 0; rc >>>= 0; rd >>>= 0;
      let t = (ra + rb) | 0;
      ra = rb ^ (rb >>> 9);
      rb = (rc + (rc << 3)) | 0;
      rc = (rc << 21) | (rc >>> 11);
      rd = (rd + 1) | 0;
      t = (t + rd) | 0;
      rc = (rc + t) | 0;
      return (t >>> 0) / 4294967296;
    };

    function halt() {
      throw SUSPEND;
    }

    function stop(kind, message, quota) {
      fatal = { kind: kind, message: message, quota: quota === undefined ? null : quota };
      suspended = true;
      halt();
    }

    function allowed(call) {
      if (suspended) halt();
      const calls = limits.allowedCalls;
      if (calls !== null && calls.indexOf(call) < 0) {
        stop('killed', 'the API call ' + call + ' is not allowed for this customer (quota: allowed API calls)', 'api_calls');
      }
    }

    function effect(op, key, value, message) {
      const seq = effectSeq++;
      if (seq < effectsApplied) return;
      push(effects, { op: op, seq: seq, t: state.clockMs, key: key, value: value, message: message });
    }

    function sensorName(s, where) {
      const name = typeof s === 'string' ? s : (s !== null && typeof s === 'object' ? s.name : undefined);
      if (typeof name !== 'string') {
        throw new TypeError(where + ' must be an entry from VV.sensor.get(name), got ' + describe(s));
      }
      if (!reflectApply(mapHas, sdc, [name])) {
        throw new VVMError(where + ': unknown sensor ' + jsonStringify(name) + ' (VV.sensor.list() shows the sensors this VV may use)');
      }
      return name;
    }

    function normalizeTask(task, where) {
      if (task === null || typeof task !== 'object') {
        throw new TypeError(where + ' must be an object {type, position, tolerance, sensors}, got ' + describe(task));
      }
      const type = task.type === undefined ? 'point' : task.type;
      if (type !== 'point') {
        throw new TypeError(where + '.type must be \'point\', got ' + describe(type));
      }
      const p = task.position;
      if (p === null || typeof p !== 'object') {
        throw new TypeError(where + '.position must be a VV.types.LatLngAlt, got ' + describe(p));
      }
      const position = new LatLngAlt(p.lat, p.lng, p.alt);
      const tolerance = task.tolerance === undefined ? 1 : checkNumber(where + '.tolerance', task.tolerance, 0, 1e6);
      const sensors = task.sensors;
      if (!isArray(sensors) || sensors.length === 0) {
        throw new TypeError(where + '.sensors must be a non-empty array of sensors from VV.sensor.get(name)');
      }
      const names = [];
      for (let k = 0; k < sensors.length; k++) push(names, sensorName(sensors[k], where + '.sensors[' + k + ']'));
      return { type: 'point', position: { lat: position.lat, lng: position.lng, alt: position.alt }, tolerance: tolerance, sensors: names };
    }

    function countTasks(n) {
      tasksRequested += n;
      if (tasksRequested > limits.maxTasks) {
        stop('killed', 'the VV asked for more than ' + limits.maxTasks + ' tasks (quota: tasks per VV)', 'tasks');
      }
    }

    // The journal must answer the same requests the program makes now; anything else means
    // the program is not deterministic and its state after a migration would be wrong.
    function expect(q, fingerprint, kinds) {
      const entry = journal[cursor];
      if (entry.q !== q || kinds.indexOf(entry.k) < 0 ||
          (fingerprint !== undefined && entry.r !== undefined && entry.r !== fingerprint)) {
        stop('failed', 'non-determinism: on replay the program made request #' + (q + 1) + ' ' + fingerprint +
          ' but its journal holds ' + (entry.r === undefined ? jsonStringify(entry.k) : entry.r) +
          ' there; a VV must decide only from what the VVM-API gave it');
      }
      cursor++;
      state.clockMs = entry.t;
      return entry;
    }

    function execute(task, callback) {
      allowed('task.execute');
      const request = normalizeTask(task, 'VV.task.execute(task): task');
      if (callback !== undefined && callback !== null && typeof callback !== 'function') {
        throw new TypeError('VV.task.execute(task, callback): callback must be a function');
      }
      countTasks(1);
      const q = requestSeq++;
      const fingerprint = jsonStringify(request);
      if (cursor >= journal.length) {
        pending = { kind: 'task', q: q, r: fingerprint, tasks: [request] };
        suspended = true;
        halt();
      }
      const entry = expect(q, fingerprint, ['done', 'reject']);
      if (entry.k === 'reject') throw new TaskRejectedError(entry.message);
      const data = jsonParse(entry.data);
      if (typeof callback === 'function') callback(data);
      return data;
    }

    function executeAll(tasks, callback) {
      allowed('task.executeAll');
      if (!isArray(tasks)) throw new TypeError('VV.task.executeAll(tasks): tasks must be an array');
      if (callback !== undefined && callback !== null && typeof callback !== 'function') {
        throw new TypeError('VV.task.executeAll(tasks, callback): callback must be a function');
      }
      const requests = [];
      for (let i = 0; i < tasks.length; i++) push(requests, normalizeTask(tasks[i], 'VV.task.executeAll(tasks): tasks[' + i + ']'));
      const results = [];
      for (let i = 0; i < requests.length; i++) push(results, undefined);
      if (requests.length === 0) return results;
      countTasks(requests.length);
      const q = requestSeq++;
      const fingerprint = jsonStringify(requests);
      let first = true;
      let remaining = requests.length;
      while (remaining > 0) {
        if (cursor >= journal.length) {
          const open = [];
          for (let i = 0; i < requests.length; i++) if (results[i] === undefined) push(open, i);
          pending = { kind: 'batch', q: q, r: first ? fingerprint : null, tasks: requests, open: open };
          suspended = true;
          halt();
        }
        const entry = expect(q, first ? fingerprint : undefined, first ? ['part', 'reject'] : ['part']);
        first = false;
        if (entry.k === 'reject') throw new TaskRejectedError(entry.message);
        const i = entry.i;
        if (typeof i !== 'number' || i < 0 || i >= requests.length || results[i] !== undefined) {
          stop('failed', 'non-determinism: the journal answers part ' + i + ' of a batch of ' + requests.length + ' twice or out of range');
        }
        const data = jsonParse(entry.data);
        results[i] = data;
        remaining--;
        if (typeof callback === 'function') callback(data, i);
      }
      return results;
    }

    function checkKey(key, where) {
      if (typeof key !== 'string' || key.length === 0 || key.length > MAX_KEY) {
        throw new TypeError(where + ': the key must be a string of 1 to ' + MAX_KEY + ' characters, got ' + describe(key));
      }
    }

    function store(key, value) {
      allowed('storage.store');
      checkKey(key, 'VV.storage.store(key, value)');
      let text;
      try {
        text = jsonStringify(value);
      } catch (e) {
        throw new TypeError('VV.storage.store(' + jsonStringify(key) + ', value): the value cannot be stored as JSON: ' + (e && e.message));
      }
      if (text === undefined) {
        throw new TypeError('VV.storage.store(' + jsonStringify(key) + ', value): the value must be JSON (not undefined or a function)');
      }
      const old = reflectApply(mapGet, storage, [key]);
      const used = storageChars - (old === undefined ? 0 : key.length + old.length) + key.length + text.length;
      if (effectSeq >= effectsApplied && used > limits.storageBytes) {
        stop('killed', 'storing ' + jsonStringify(key) + ' would use ' + used + ' bytes of storage, more than the ' +
          limits.storageBytes + ' allowed (quota: storage bytes)', 'storage');
      }
      storageChars = used;
      reflectApply(mapSet, storage, [key, text]);
      effect('store', key, text, null);
    }

    function load(key) {
      allowed('storage.load');
      checkKey(key, 'VV.storage.load(key)');
      const text = reflectApply(mapGet, storage, [key]);
      return text === undefined ? undefined : jsonParse(text);
    }

    function list(pattern) {
      allowed('storage.list');
      let re = null;
      if (pattern !== undefined && pattern !== null) {
        try {
          re = pattern instanceof RealRegExp ? new RealRegExp(pattern.source, pattern.flags.replace('g', '').replace('y', '')) : new RealRegExp(stringOf(pattern));
        } catch (e) {
          throw new SyntaxError('VV.storage.list(pattern): ' + (e && e.message));
        }
      }
      const keys = [];
      for (const key of reflectApply(mapKeys, storage, [])) {
        if (re === null || reflectApply(regExpTest, re, [key])) push(keys, key);
      }
      reflectApply(arraySort, keys, []);
      return keys;
    }

    function remove(key) {
      allowed('storage.remove');
      checkKey(key, 'VV.storage.remove(key)');
      const old = reflectApply(mapGet, storage, [key]);
      if (old === undefined) return false;
      storageChars -= key.length + old.length;
      reflectApply(mapDelete, storage, [key]);
      effect('remove', key, null, null);
      return true;
    }

    function text(value) {
      if (typeof value === 'string') return value;
      if (value !== null && typeof value === 'object') {
        try {
          const s = jsonStringify(value);
          if (s !== undefined) return s;
        } catch (e) { /* fall through to String() */ }
      }
      return stringOf(value);
    }

    function logLine(args) {
      let line = '';
      for (let i = 0; i < args.length; i++) line += (i > 0 ? ' ' : '') + text(args[i]);
      if (line.length > MAX_LINE) line = reflectApply(stringSlice, line, [0, MAX_LINE]) + '…';
      effect('log', null, null, line);
    }

    const catalogEntries = [];
    for (let i = 0; i < catalog.length; i++) push(catalogEntries, sdcEntry(catalog[i]));
    const names = [];
    for (let i = 0; i < catalog.length; i++) push(names, catalog[i].name);
    const known = reflectApply(arrayJoin, names, [', ']);

    const VV = freeze({
      id: input.vvId,
      name: input.vvName,
      sensor: freeze({
        get: function get(name) {
          allowed('sensor.get');
          if (typeof name !== 'string') throw new TypeError('VV.sensor.get(name): name must be a string, got ' + describe(name));
          const e = reflectApply(mapGet, sdc, [name]);
          if (e === undefined) {
            throw new VVMError('VV.sensor.get: unknown sensor ' + jsonStringify(name) + ' (this VV may use: ' + known + ')');
          }
          return sdcEntry(e);
        },
        list: function list() {
          allowed('sensor.list');
          return reflectApply(arraySlice, catalogEntries, []);
        },
      }),
      types: freeze({ LatLngAlt: LatLngAlt, LatLng: LatLng }),
      task: freeze({ execute: execute, executeAll: executeAll }),
      storage: freeze({ store: store, load: load, list: list, remove: remove }),
      log: function log(...args) { allowed('log'); logLine(args); },
      errors: freeze({ TaskRejectedError: TaskRejectedError, VVMError: VVMError }),
    });
    const stdOut = freeze({ println: function println(msg) { allowed('log'); logLine([msg]); } });

    state.globals = {
      VV: VV,
      TaskRejectedError: TaskRejectedError,
      logInfo: function logInfo(msg) { allowed('log'); logLine([msg]); },
      getStdOut: function getStdOut() { return stdOut; },
    };
    state.rethrow = function (e) { if (e === SUSPEND || suspended) throw SUSPEND; };
    state.isSuspended = function () { return suspended; };
    state.outcome = function () {
      let status;
      if (fatal !== null) status = fatal.kind;
      else if (pending !== null) status = 'suspended';
      else status = 'returned';
      return jsonStringify({
        status: status,
        pending: pending,
        fatal: fatal,
        effects: effects,
        effectsTotal: effectSeq,
        consumed: cursor,
        journalLength: journal.length,
        requests: requestSeq,
        storageBytes: storageChars,
        tainted: tainted,
      });
    };
    return state;
  }

  // --- what the host calls ----------------------------------------------------------------------
  // Every host function wants the key this file was installed with: the program can reach
  // `__cpcc_host` through globalThis, but not the key, which lives only in this closure.
  function host(key, what) {
    if (key !== hostKey || running) throw new TypeError(what + ' is for the platform only');
  }

  function constant(name, value) {
    defineProperty(global, name, { value: value, writable: false, enumerable: false, configurable: false });
  }

  // Hooks of the instrumented program: they act on the current run.
  constant('__cpcc_rethrow', function (e) { if (run !== null) run.rethrow(e); });
  constant('__cpcc_suspended', function () { return run !== null && run.isSuspended(); });

  constant('__cpcc_host', freeze({
    // The VV's SDC entries: part of its checkpoint, the same for every run.
    setCatalog: function (key, json) { host(key, 'setCatalog'); catalog = jsonParse(json); },
    setProgram: function (key, fn) { host(key, 'setProgram'); program = fn; },
    // Journal entries as JSON text; the readings stay text until a run consumes them, so a
    // program that changes the readings it got cannot change what the next run gets.
    append: function (key, json) {
      host(key, 'append');
      const entries = jsonParse(json);
      for (let i = 0; i < entries.length; i++) {
        const e = entries[i];
        push(journal, freeze({ q: e.q, k: e.k, t: e.t, r: e.r, i: e.i, message: e.message,
          data: e.data === undefined ? undefined : jsonStringify(e.data) }));
      }
      return journal.length;
    },
    step: function (key, json) {
      host(key, 'step');
      run = null;
      if (!resetGlobals()) tainted = true;
      run = newRun(jsonParse(json));
      for (let i = 0; i < RUN_GLOBALS.length; i++) {
        const name = RUN_GLOBALS[i];
        defineProperty(global, name, { value: run.globals[name], writable: false, enumerable: false, configurable: true });
      }
      running = true;
      try {
        reflectApply(program, undefined, []);
      } finally {
        running = false;
      }
    },
    // V8 stopped the program (a quota): its `finally` above did not run.
    abort: function (key) {
      if (key !== hostKey) throw new TypeError('abort is for the platform only');
      running = false;
    },
    // Also clears what the run left on the global object: if something cannot be cleared,
    // the outcome says the context is tainted and the host does not reuse it.
    outcome: function (key) {
      host(key, 'outcome');
      if (!resetGlobals()) tainted = true;
      return run === null ? 'null' : run.outcome();
    },
  }));

  baseline = new RealSet(ownKeys(global));
  for (let i = 0; i < RUN_GLOBALS.length; i++) reflectApply(setAdd, baseline, [RUN_GLOBALS[i]]);
})
