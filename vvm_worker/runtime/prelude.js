// The VVM-API inside a virtual vehicle's V8 context (DESIGN.md section 2).
//
// A step runs the VV's program from its first line. Every call that needs the outside world
// (a task's readings, a rejection) is answered from the journal; the first call without an
// answer becomes the pending request and the step ends: the call throws SUSPEND, and every
// later VVM-API call throws it again. The program is instrumented when it is loaded so that
// its own `catch` clauses rethrow SUSPEND and its `finally` clauses are skipped while
// suspended: as blocking code, nothing after the pending call has happened yet.
//
// Effects (storage writes, log lines) are numbered from the program's start; only those at or
// after `effectsApplied` are reported to the host, so replaying a step never applies an effect
// twice. Storage itself is rebuilt by the replay, which makes `load` deterministic.
//
// Everything the host reads back goes through `__cpcc_outcome`, which uses functions captured
// here before the program runs: a program that replaces JSON, Object or Array methods can
// break itself, not the platform.
(function (input) {
  'use strict';

  const global = globalThis;
  const jsonStringify = JSON.stringify;
  const jsonParse = JSON.parse;
  const defineProperty = Object.defineProperty;
  const freeze = Object.freeze;
  const objectKeys = Object.keys;
  const isArray = Array.isArray;
  const numberIsFinite = Number.isFinite;
  const mathFloor = Math.floor;
  const mathImul = Math.imul;
  const stringOf = String;
  const RealDate = Date;
  const RealError = Error;
  const RealRegExp = RegExp;
  const regExpTest = RegExp.prototype.test;
  const reflectApply = Reflect.apply;
  const arraySort = Array.prototype.sort;

  const journal = input.journal;
  const effectsApplied = input.effectsApplied;
  const limits = input.limits;
  const catalog = input.catalog;

  // --- outcome state -------------------------------------------------------------------
  const SUSPEND = freeze({ cpccSuspend: true });
  let suspended = false;
  let pending = null;
  let fatal = null; // {kind, message, quota?}: ends the VV whatever the program does next
  const effects = [];
  let effectSeq = 0;
  let cursor = 0; // next journal entry
  let requestSeq = 0; // ordinal of the next request (execute or executeAll)
  let clockMs = input.startMs;
  let storageChars = 0;
  const storage = new Map();

  function push(list, item) {
    list[list.length] = item;
  }

  function halt() {
    // Unwind the program: SUSPEND passes through every instrumented catch and finally.
    throw SUSPEND;
  }

  function stop(kind, message, quota) {
    fatal = { kind: kind, message: message, quota: quota === undefined ? null : quota };
    suspended = true;
    halt();
  }

  function live() {
    if (suspended) halt();
  }

  function allowed(call) {
    live();
    const calls = limits.allowedCalls;
    if (calls !== null && calls.indexOf(call) < 0) {
      stop('killed', 'the API call ' + call + ' is not allowed for this customer (quota: allowed API calls)', 'api_calls');
    }
  }

  function effect(op, key, value, message) {
    const seq = effectSeq++;
    if (seq < effectsApplied) return;
    push(effects, { op: op, seq: seq, t: clockMs, key: key, value: value, message: message });
  }

  // --- determinism: seeded Math.random and a logical clock --------------------------------
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
  function random() {
    ra >>>= 0; rb >>>= 0; rc >>>= 0; rd >>>= 0;
    let t = (ra + rb) | 0;
    ra = rb ^ (rb >>> 9);
    rb = (rc + (rc << 3)) | 0;
    rc = (rc << 21) | (rc >>> 11);
    rd = (rd + 1) | 0;
    t = (t + rd) | 0;
    rc = (rc + t) | 0;
    return (t >>> 0) / 4294967296;
  }
  defineProperty(Math, 'random', { value: random, writable: true, configurable: true });

  function VVDate(...args) {
    if (new.target === undefined) return new RealDate(clockMs).toString();
    if (args.length === 0) return new RealDate(clockMs);
    return new RealDate(...args);
  }
  VVDate.prototype = RealDate.prototype;
  VVDate.now = function now() { return clockMs; };
  VVDate.parse = RealDate.parse;
  VVDate.UTC = RealDate.UTC;
  defineProperty(RealDate.prototype, 'constructor', { value: VVDate, writable: true, configurable: true });
  defineProperty(global, 'Date', { value: VVDate, writable: true, configurable: true });

  // --- errors the program can catch --------------------------------------------------------
  class TaskRejectedError extends RealError {
    constructor(message) {
      super(message);
      this.name = 'TaskRejectedError';
    }
  }
  class VVMError extends RealError {
    constructor(message) {
      super(message);
      this.name = 'VVMError';
    }
  }

  // --- types ---------------------------------------------------------------------------------
  function checkNumber(what, value, lo, hi) {
    if (typeof value !== 'number' || !numberIsFinite(value)) {
      throw new RangeError(what + ' must be a finite number, got ' + describe(value));
    }
    if (value < lo || value > hi) {
      throw new RangeError(what + ' ' + value + ' is outside ' + lo + '..' + hi);
    }
    return value;
  }

  function describe(value) {
    if (typeof value === 'string') return jsonStringify(value);
    if (value === null || typeof value !== 'object') return stringOf(value);
    return isArray(value) ? 'an array' : 'an object';
  }

  const MAX_ALT_M = 20000;

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

  // --- sensors (the system-wide device catalog, as this VV may use it) ---------------------
  const sdc = new Map();
  for (let i = 0; i < catalog.length; i++) {
    const e = catalog[i];
    sdc.set(e.name, e);
  }

  function sdcEntry(e) {
    return freeze({
      name: e.name,
      description: e.name,
      kind: e.kind,
      unit: e.unit,
      params: freeze(jsonParse(jsonStringify(e.params || {}))),
    });
  }

  function sensorName(s, where) {
    const name = typeof s === 'string' ? s : (s !== null && typeof s === 'object' ? s.name : undefined);
    if (typeof name !== 'string') {
      throw new TypeError(where + ' must be an entry from VV.sensor.get(name), got ' + describe(s));
    }
    if (!sdc.has(name)) {
      throw new VVMError(where + ': unknown sensor ' + jsonStringify(name) + ' (VV.sensor.list() shows the sensors this VV may use)');
    }
    return name;
  }

  // --- tasks -------------------------------------------------------------------------------
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

  let tasksRequested = 0;
  function countTask(n) {
    tasksRequested += n;
    if (tasksRequested > limits.maxTasks) {
      stop('killed', 'the VV asked for more than ' + limits.maxTasks + ' tasks (quota: tasks per VV)', 'tasks');
    }
  }

  // The journal must answer the same requests the program makes now; anything else means the
  // program is not deterministic and its state after a migration would be wrong.
  function expect(q, fingerprint, kinds) {
    const entry = journal[cursor];
    if (entry.q !== q || kinds.indexOf(entry.k) < 0 ||
        (fingerprint !== undefined && entry.r !== undefined && entry.r !== fingerprint)) {
      stop('failed', 'non-determinism: on replay the program made request #' + (q + 1) + ' ' + fingerprint +
        ' but its journal holds ' + (entry.r === undefined ? jsonStringify(entry.k) : entry.r) +
        ' there; a VV must decide only from what the VVM-API gave it');
    }
    cursor++;
    clockMs = entry.t;
    return entry;
  }

  function execute(task, callback) {
    allowed('task.execute');
    const request = normalizeTask(task, 'VV.task.execute(task): task');
    if (callback !== undefined && callback !== null && typeof callback !== 'function') {
      throw new TypeError('VV.task.execute(task, callback): callback must be a function');
    }
    countTask(1);
    const q = requestSeq++;
    const fingerprint = jsonStringify(request);
    if (cursor >= journal.length) {
      pending = { kind: 'task', q: q, r: fingerprint, tasks: [request] };
      suspended = true;
      halt();
    }
    const entry = expect(q, fingerprint, ['done', 'reject']);
    if (entry.k === 'reject') throw new TaskRejectedError(entry.message);
    const data = entry.data;
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
    countTask(requests.length);
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
      const data = entry.data;
      results[i] = data;
      remaining--;
      if (typeof callback === 'function') callback(data, i);
    }
    return results;
  }

  // --- storage -----------------------------------------------------------------------------
  const MAX_KEY = 128;

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
    const before = storage.has(key) ? key.length + storage.get(key).length : 0;
    const used = storageChars - before + key.length + text.length;
    if (effectSeq >= effectsApplied && used > limits.storageBytes) {
      stop('killed', 'storing ' + jsonStringify(key) + ' would use ' + used + ' bytes of storage, more than the ' +
        limits.storageBytes + ' allowed (quota: storage bytes)', 'storage');
    }
    storageChars = used;
    storage.set(key, text);
    effect('store', key, text, null);
  }

  function load(key) {
    allowed('storage.load');
    checkKey(key, 'VV.storage.load(key)');
    const text = storage.get(key);
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
    for (const key of storage.keys()) {
      if (re === null || reflectApply(regExpTest, re, [key])) push(keys, key);
    }
    reflectApply(arraySort, keys, []);
    return keys;
  }

  function remove(key) {
    allowed('storage.remove');
    checkKey(key, 'VV.storage.remove(key)');
    if (!storage.has(key)) return false;
    storageChars -= key.length + storage.get(key).length;
    storage.delete(key);
    effect('remove', key, null, null);
    return true;
  }

  // --- log -----------------------------------------------------------------------------------
  const MAX_LINE = 4000;

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
    live();
    let line = '';
    for (let i = 0; i < args.length; i++) line += (i > 0 ? ' ' : '') + text(args[i]);
    if (line.length > MAX_LINE) line = line.slice(0, MAX_LINE) + '…';
    effect('log', null, null, line);
  }

  function log(...args) {
    allowed('log');
    logLine(args);
  }

  // --- the global object ------------------------------------------------------------------
  const frozenCatalog = [];
  for (let i = 0; i < catalog.length; i++) push(frozenCatalog, sdcEntry(catalog[i]));

  const VV = freeze({
    id: input.vvId,
    name: input.vvName,
    sensor: freeze({
      get: function get(name) {
        allowed('sensor.get');
        if (typeof name !== 'string') throw new TypeError('VV.sensor.get(name): name must be a string, got ' + describe(name));
        const e = sdc.get(name);
        if (e === undefined) {
          throw new VVMError('VV.sensor.get: unknown sensor ' + jsonStringify(name) + ' (this VV may use: ' + objectKeys(sdcNames()).join(', ') + ')');
        }
        return sdcEntry(e);
      },
      list: function list() {
        allowed('sensor.list');
        return frozenCatalog.slice();
      },
    }),
    types: freeze({ LatLngAlt: LatLngAlt, LatLng: LatLng }),
    task: freeze({ execute: execute, executeAll: executeAll }),
    storage: freeze({ store: store, load: load, list: list, remove: remove }),
    log: log,
    errors: freeze({ TaskRejectedError: TaskRejectedError, VVMError: VVMError }),
  });

  function sdcNames() {
    const names = {};
    for (let i = 0; i < catalog.length; i++) names[catalog[i].name] = true;
    return names;
  }

  const stdOut = freeze({ println: function println(msg) { allowed('log'); logLine([msg]); } });

  function constant(name, value) {
    defineProperty(global, name, { value: value, writable: false, enumerable: false, configurable: false });
  }
  constant('VV', VV);
  constant('TaskRejectedError', TaskRejectedError);
  constant('logInfo', function logInfo(msg) { allowed('log'); logLine([msg]); });
  constant('getStdOut', function getStdOut() { return stdOut; });

  // Hooks for the instrumented program: reserved names a program may not use itself.
  constant('__cpcc_rethrow', function (e) { if (e === SUSPEND || suspended) throw SUSPEND; });
  constant('__cpcc_suspended', function () { return suspended; });
  constant('__cpcc_outcome', function () {
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
    });
  });
})
