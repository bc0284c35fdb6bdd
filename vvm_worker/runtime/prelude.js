// The VVM-API inside a virtual vehicle's V8 isolate (DESIGN.md section 2).
//
// One isolate serves one VV for as long as the VV stays on a host (a warm context). It is
// set up once: the built-ins are frozen, so nothing a program does to them can outlive the run
// that did it, and everything that could observe the host (timers, console, WebAssembly,
// Atomics, WeakRef, Intl, Temporal, code generation from strings) is removed or disabled.
//
// A run starts the program at its first line (deterministic replay): each VVM-API call that
// needs the outside world is answered from the journal; the first one without an answer
// becomes the pending request. Where the program calls it in its own body and the platform
// compiled the program as a generator (instrument.py), the call yields and the program stays
// suspended there: the next step of this context resumes it with the new answer (see
// `canResume`). Anywhere else the step ends by SUSPEND: the call throws it, and every later
// VVM-API call throws it again, and the next step replays. The program is instrumented when it
// is loaded so that its own `catch` clauses rethrow SUSPEND and its `finally` clauses are
// skipped while suspended.
//
// Effects (storage writes, log lines) are numbered from the program's start; only those at or
// after `effectsApplied` are reported to the host, so replaying never applies an effect twice.
// Storage itself is rebuilt by the replay, which makes `load` deterministic.
//
// In a warm context a step that replays re-does what the last run did, so what a program
// cannot tell apart is kept from one run to the next: the journal's readings and requests,
// parsed (JournalEntry), and the strings of the last run's storage.
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
  const objectKeys = Object.keys;
  const numberIsFinite = Number.isFinite;
  const numberIsSafeInteger = Number.isSafeInteger;
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
  const stringIsWellFormed = String.prototype.isWellFormed;
  const stringToWellFormed = String.prototype.toWellFormed;
  const stringIndexOf = String.prototype.indexOf;
  const stringLastIndexOf = String.prototype.lastIndexOf;
  const stringReplaceAll = String.prototype.replaceAll;
  const stringReplace = String.prototype.replace;
  const regExpExec = RegExp.prototype.exec;
  const objectIsExtensible = Object.isExtensible;
  const mathFloor = Math.floor;
  const mathMin = Math.min;
  const reflectConstruct = Reflect.construct;
  const symbolIterator = Symbol.iterator;

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
  // Promise jobs run when V8's microtask queue is drained: after a step has returned, so at
  // other points warm and replayed (and async functions stopped at their first await). A VV
  // waits by blocking calls: Promise goes (async functions, await and import() are refused
  // when the program is submitted; Array.fromAsync is the one other way to a promise).
  delete global.Promise;
  delete Array.fromAsync;

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

  // --- memory outside the heap: ArrayBuffers and typed arrays --------------------------------
  // Their bytes live outside V8's heap, where the heap quota does not see them. Every
  // allocation goes through these constructors and counts against the same quota, added up
  // over the run (the same sum warm and replayed: see run.allocate).
  const RealArrayBuffer = ArrayBuffer;
  function toLength(value) {
    const n = +value;
    if (!(n > 0)) return 0;
    return mathMin(mathFloor(n), 9007199254740991);
  }
  function allocate(bytes, what) {
    if (run !== null && bytes > 0) run.allocate(bytes, what);
  }
  function replaceConstructor(name, Original, bytesOf) {
    function Checked(...args) {
      if (new.target === undefined) return reflectApply(Original, this, args);
      allocate(bytesOf(args), name);
      return reflectConstruct(Original, args, new.target === Checked ? Original : new.target);
    }
    defineProperty(Checked, 'name', { value: name });
    defineProperty(Checked, 'length', { value: Original.length });
    for (const key of ownKeys(Original)) {
      if (key === 'prototype' || key === 'length' || key === 'name') continue;
      defineProperty(Checked, key, getOwnPropertyDescriptor(Original, key));
    }
    Object.setPrototypeOf(Checked, getPrototypeOf(Original));
    defineProperty(Checked, 'prototype', { value: Original.prototype, writable: false });
    defineProperty(Original.prototype, 'constructor', { value: Checked, writable: true, configurable: true });
    defineProperty(global, name, { value: Checked, writable: true, configurable: true });
  }
  replaceConstructor('ArrayBuffer', RealArrayBuffer, function (args) {
    const options = args[1];
    const most = options !== null && typeof options === 'object' ? toLength(options.maxByteLength) : 0;
    return toLength(args[0]) > most ? toLength(args[0]) : most;
  });
  const arrayBufferTransfer = RealArrayBuffer.prototype.transfer;
  const arrayBufferTransferFixed = RealArrayBuffer.prototype.transferToFixedLength;
  defineProperty(RealArrayBuffer.prototype, 'transfer', { value: function transfer(length) {
    allocate(toLength(length), 'ArrayBuffer.prototype.transfer');
    return reflectApply(arrayBufferTransfer, this, arguments);
  }, writable: true, configurable: true });
  defineProperty(RealArrayBuffer.prototype, 'transferToFixedLength', { value: function transferToFixedLength(length) {
    allocate(toLength(length), 'ArrayBuffer.prototype.transferToFixedLength');
    return reflectApply(arrayBufferTransferFixed, this, arguments);
  }, writable: true, configurable: true });
  for (const name of ['Int8Array', 'Uint8Array', 'Uint8ClampedArray', 'Int16Array', 'Uint16Array',
    'Int32Array', 'Uint32Array', 'Float16Array', 'Float32Array', 'Float64Array', 'BigInt64Array',
    'BigUint64Array']) {
    const Original = global[name];
    if (typeof Original !== 'function') continue;
    const size = Original.BYTES_PER_ELEMENT;
    replaceConstructor(name, Original, function (args) {
      const a = args[0];
      if (a === null || a === undefined) return 0;
      if (typeof a !== 'object') return toLength(a) * size;
      if (a instanceof RealArrayBuffer) return 0; // a view of a buffer that exists
      return typeof a.length === 'number' ? toLength(a.length) * size : 0;
    });
  }

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
  // The global object's own prototype (an object of its own in V8, not Object.prototype):
  // what a run put on it would outlive the run.
  push(roots, getPrototypeOf(global));
  harden(roots);

  const RUN_GLOBALS = ['VV', 'TaskRejectedError', 'MessageError', 'ImageError', 'logInfo', 'getStdOut'];
  let baseline = null; // the global object's own keys once this file has run
  const baselineProto = getPrototypeOf(global);

  // Deletes what the last run added to the global object. False when it cannot, and the
  // context must not be reused.
  function resetGlobals() {
    if (getPrototypeOf(global) !== baselineProto || !objectIsExtensible(global)) return false;
    const keys = ownKeys(global);
    for (let i = 0; i < keys.length; i++) {
      if (!reflectApply(setHas, baseline, [keys[i]]) && !reflectDeleteProperty(global, keys[i])) return false;
    }
    return true;
  }

  // --- the context's own data: catalog, journal, program ------------------------------------
  let catalog = [];
  const journal = []; // JournalEntry, in order
  let program = null;
  let tainted = false;

  // Readings nested deeper than this stay JSON text, parsed again by each run: copying them
  // recursively could overflow a stack that parsing does not.
  const MAX_COPY_DEPTH = 16;

  function depthAtMost(value, depth) {
    if (value === null || typeof value !== 'object') return true;
    if (depth === 0) return false;
    if (isArray(value)) {
      for (let i = 0; i < value.length; i++) if (!depthAtMost(value[i], depth - 1)) return false;
      return true;
    }
    const keys = objectKeys(value);
    for (let i = 0; i < keys.length; i++) if (!depthAtMost(value[keys[i]], depth - 1)) return false;
    return true;
  }

  // A fresh copy of a value JSON.parse made (plain arrays, plain objects, primitives), equal to
  // what parsing its text again would give and three to five times cheaper: no number is read
  // from text again. `for in` sees only the object's own keys (the frozen Object.prototype has
  // no enumerable property, and a program cannot add one). Assigning a key Object.prototype has
  // is safe: every such property is an accessor whose setter defines the property on the object
  // (enableOverride), except `__proto__`.
  function copyJson(value) {
    if (value === null || typeof value !== 'object') return value;
    if (isArray(value)) {
      const n = value.length;
      const array = [];
      for (let i = 0; i < n; i++) push(array, copyJson(value[i]));
      return array;
    }
    const object = {};
    for (const key in value) {
      if (key === '__proto__') {
        defineProperty(object, key, { value: copyJson(value[key]), writable: true, enumerable: true, configurable: true });
      } else {
        object[key] = copyJson(value[key]);
      }
    }
    return object;
  }

  // One answer of the journal. The first run that reads it (in a new context, the only one)
  // parses its readings from text and writes the request it answers as text to compare, as
  // runs always did; a second run keeps both parsed for every run after it. The parsed
  // readings are never handed out: each run gets its own copy, so a program that changes the
  // readings it got cannot change what the next run gets.
  class JournalEntry {
    constructor(e) {
      this.q = e.q;
      this.k = e.k;
      this.t = e.t;
      this.r = e.r;
      this.i = e.i;
      this.message = e.message;
      this.name = e.name; // of the error an "err" answer throws
      this.text = e.data === undefined ? undefined : jsonStringify(e.data);
      this.readings = undefined; // parsed from `text`, once a second run reads them
      this.reads = 0;
      this.request = undefined; // `r` parsed, once compared a second time (null: not comparable)
      this.compared = false;
    }

    // The readings for the program, a copy of its own.
    freshData() {
      if (this.readings !== undefined) return copyJson(this.readings);
      const data = jsonParse(this.text);
      this.reads++;
      if (this.reads === 2 && depthAtMost(data, MAX_COPY_DEPTH)) {
        this.readings = data;
        this.text = undefined;
        return copyJson(data);
      }
      return data;
    }

    // Whether this entry answers `request` (a task, or the tasks of a batch, as normalizeTask
    // makes them): whether the request's JSON text is `r`.
    answers(request) {
      if (this.request === undefined) {
        if (!this.compared) {
          this.compared = true;
          return jsonStringify(request) === this.r;
        }
        this.request = comparableRequest(this.r);
      }
      return this.request === null ? jsonStringify(request) === this.r : sameRequest(request, this.request);
    }
  }

  // `r` parsed, when it is exactly the text the prelude writes for a task or a batch of tasks;
  // null otherwise. For such a text, sameRequest() compares values where the texts would be
  // compared, with the same result (finite numbers and strings are equal exactly when their
  // JSON texts are, and the keys are in the same order), and without writing the program's
  // request as text again in every run.
  function comparableRequest(r) {
    if (typeof r !== 'string') return null;
    let parsed;
    try {
      parsed = jsonParse(r);
    } catch (e) {
      return null;
    }
    if (isArray(parsed) ? !everyTaskShaped(parsed) : !taskShaped(parsed)) return null;
    return jsonStringify(parsed) === r ? parsed : null;
  }

  function keysAre(value, expected) {
    if (value === null || typeof value !== 'object' || isArray(value)) return false;
    const keys = objectKeys(value);
    if (keys.length !== expected.length) return false;
    for (let i = 0; i < keys.length; i++) if (keys[i] !== expected[i]) return false;
    return true;
  }

  const TASK_KEYS = freeze(['type', 'position', 'tolerance', 'sensors']);
  const POSITION_KEYS = freeze(['lat', 'lng', 'alt']);

  function taskShaped(task) {
    return keysAre(task, TASK_KEYS) && keysAre(task.position, POSITION_KEYS) && isArray(task.sensors);
  }

  function everyTaskShaped(tasks) {
    for (let i = 0; i < tasks.length; i++) if (!taskShaped(tasks[i])) return false;
    return true;
  }

  // `made` comes from normalizeTask, `recorded` from comparableRequest.
  function sameTask(made, recorded) {
    const p = made.position;
    const r = recorded.position;
    if (made.type !== recorded.type || p.lat !== r.lat || p.lng !== r.lng || p.alt !== r.alt ||
        made.tolerance !== recorded.tolerance) return false;
    const names = made.sensors;
    const recordedNames = recorded.sensors;
    if (names.length !== recordedNames.length) return false;
    for (let i = 0; i < names.length; i++) if (names[i] !== recordedNames[i]) return false;
    return true;
  }

  function sameRequest(made, recorded) {
    if (isArray(made) !== isArray(recorded)) return false;
    if (!isArray(made)) return sameTask(made, recorded);
    if (made.length !== recorded.length) return false;
    for (let i = 0; i < made.length; i++) if (!sameTask(made[i], recorded[i])) return false;
    return true;
  }

  // --- one run of the program -----------------------------------------------------------------
  const SUSPEND = freeze({ cpccSuspend: true });
  // What a VVM-API call yields while it waits for an answer (see executeSteps).
  const PARK = freeze({ cpccPark: true });
  const TASK_ANSWERS = freeze(['done', 'reject']);
  const FIRST_PART_ANSWERS = freeze(['part', 'reject']);
  const PART_ANSWERS = freeze(['part']);
  const CALL_ANSWERS = freeze(['ret', 'err']);
  const MESSAGE_ANSWERS = freeze(['msg']);
  const MAX_TIMEOUT_S = 86400;
  // Longer than any VV's name (or id) or picture reference: refused before they reach a journal.
  const MAX_NAME = 128;
  const MAX_PICTURE_REF = 256;
  const MAX_RESIZE = 4096;
  const CHANNELS = freeze(['r', 'g', 'b']);
  // What crop and resize copy from the picture they are given into the one they return.
  const PICTURE_SOURCE_KEYS = freeze(['sensor', 'time', 'position']);
  const MAX_ALT_M = 20000;
  // Below 0 is depth (an underwater vehicle's task); no sea is deeper.
  const MIN_ALT_M = -11000;
  const MAX_KEY = 128;
  const MAX_LINE = 4000;
  // Deeper values could not be read back by the platform (nor by most JSON readers).
  const MAX_DEPTH = 100;
  // In a JSON text: an escape of U+0000 or of a lone surrogate (JSON.stringify writes a lone
  // surrogate as an escape and a whole pair as it is), after an even run of backslashes.
  const UNSTORABLE_ESCAPE = /(?:^|[^\\])(?:\\\\)*\\u(?:0000|d[89a-f])/;
  const RESET_MATCH = /(?:)/;

  // Fast paths in native code for what is common (a replay runs these loops in a new isolate,
  // before V8 has compiled them): ASCII text, and text with few brackets.
  const NON_ASCII = /[^\x00-\x7f]/;
  const NOT_OPENING = /[^[{]+/g;

  // Bytes of `s` in UTF-8 (what the storage quota counts). `s` is well-formed.
  function utf8Bytes(s) {
    if (!reflectApply(regExpTest, NON_ASCII, [s])) return s.length;
    let n = s.length;
    for (let i = 0; i < s.length; i++) {
      const c = s.charCodeAt(i);
      if (c < 0x80) continue;
      if (c < 0x800) n += 1;
      else if (c >= 0xd800 && c <= 0xdbff) { n += 2; i++; } // a pair: 2 units, 4 bytes
      else n += 2;
    }
    return n;
  }

  // How deep arrays and objects nest in a JSON text (strings skipped); 0 when it has too few
  // brackets to nest more than MAX_DEPTH.
  function jsonDepth(text) {
    // Nesting deeper than MAX_DEPTH takes more opening brackets (and twice as many characters).
    if (text.length <= 2 * MAX_DEPTH) return 0;
    if (reflectApply(stringReplace, text, [NOT_OPENING, '']).length <= MAX_DEPTH) return 0;
    let depth = 0;
    let most = 0;
    for (let i = 0; i < text.length; i++) {
      const c = text.charCodeAt(i);
      if (c === 34) { // a string: to its closing quote
        for (i++; i < text.length; i++) {
          const d = text.charCodeAt(i);
          if (d === 92) i++;
          else if (d === 34) break;
        }
      } else if (c === 91 || c === 123) {
        depth++;
        if (depth > most) most = depth;
      } else if (c === 93 || c === 125) {
        depth--;
      }
    }
    return most;
  }

  function describe(value) {
    if (typeof value === 'string') return jsonStringify(value);
    if (value === null || typeof value !== 'object') return stringOf(value);
    return isArray(value) ? 'an array' : 'an object';
  }

  // The JSON text of `value` as VV.storage.store keeps it and VV.message.send sends it (it is
  // `verb`: 'stored' or 'sent'); else a TypeError or RangeError saying why, after `where`, or
  // after `where("KEY", value)` when a storage key is given (written only for an error: a
  // replay stores thousands of values).
  function storableText(value, verb, where, key) {
    let text;
    try {
      text = jsonStringify(value);
    } catch (e) {
      throw new TypeError(callPlace(where, key) + ': the value cannot be ' + verb + ' as JSON: ' + (e && e.message));
    }
    if (text === undefined) {
      throw new TypeError(callPlace(where, key) + ': the value must be JSON (not undefined or a function)');
    }
    if (reflectApply(regExpTest, UNSTORABLE_ESCAPE, [text])) {
      throw new RangeError(callPlace(where, key) + ': the value holds a string with a lone surrogate (half of a UTF-16 pair) or the character U+0000, which cannot be ' + verb);
    }
    if (jsonDepth(text) > MAX_DEPTH) {
      throw new RangeError(callPlace(where, key) + ': the value nests arrays and objects more than ' + MAX_DEPTH + ' levels deep');
    }
    return text;
  }

  function callPlace(where, key) {
    return key === undefined ? where : where + '(' + jsonStringify(key) + ', value)';
  }

  // A string the platform can keep as text (valid Unicode, no U+0000).
  function plainString(s) {
    return reflectApply(stringIsWellFormed, s, []) && reflectApply(stringIndexOf, s, ['\u0000']) < 0;
  }

  // `hi` undefined: no upper bound (the host compares with the picture's size).
  function checkInteger(what, value, lo, hi) {
    if (typeof value !== 'number' || !numberIsSafeInteger(value)) {
      throw new TypeError(what + ' must be an integer, got ' + describe(value));
    }
    if (hi === undefined && value < lo) {
      throw new RangeError(what + ' must be ' + lo + ' or more, got ' + value);
    }
    if (value < lo || value > hi) {
      throw new RangeError(what + ' ' + value + ' is outside ' + lo + '..' + hi);
    }
    return value;
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

  // Where in the program a VVM-API call is being made: [line, column] of the innermost frame
  // of the program's script (vv.js) on the stack, as V8 counts them in that script, or null.
  // For reports only (a dry run lists the line of each task; a quota kill says where): nothing
  // the program can observe depends on it (string functions only: a RegExp would change
  // RegExp's legacy statics). Called once per step at most.
  const PROGRAM_SCRIPT = 'vv.js:';
  function callSite() {
    // A call made at the edge of the stack: no place rather than a RangeError that only the
    // run making the request would see (a replay answers the call without asking here).
    try {
      return placeIn(new RealError().stack);
    } catch (e) {
      return null;
    }
  }
  function placeIn(stack) {
    if (typeof stack !== 'string') return null;
    let start = 0;
    while (start < stack.length) {
      let end = reflectApply(stringIndexOf, stack, ['\n', start]);
      if (end < 0) end = stack.length;
      let frame = reflectApply(stringSlice, stack, [start, end]);
      start = end + 1;
      // "    at NAME (PLACE)" or "    at PLACE": the place ends the line (a name cannot).
      if (frame.length > 0 && frame[frame.length - 1] === ')') {
        frame = reflectApply(stringSlice, frame, [reflectApply(stringLastIndexOf, frame, ['(']) + 1, frame.length - 1]);
      } else {
        frame = reflectApply(stringSlice, frame, [reflectApply(stringLastIndexOf, frame, [' ']) + 1]);
      }
      if (reflectApply(stringIndexOf, frame, [PROGRAM_SCRIPT]) !== 0) continue;
      const colon = reflectApply(stringLastIndexOf, frame, [':']);
      const line = +reflectApply(stringSlice, frame, [PROGRAM_SCRIPT.length, colon]);
      const column = +reflectApply(stringSlice, frame, [colon + 1]);
      if (line > 0 && column > 0) return [line, column];
    }
    return null;
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
  // What a VV.message call throws when the message cannot be sent (no such VV, a quota).
  class MessageError extends RealError {
    constructor(message) {
      super(message);
      defineProperty(this, 'name', { value: 'MessageError', writable: true, configurable: true });
    }
  }
  // What a VV.image call throws for a picture the host cannot use (not received, a region
  // outside it, unreadable).
  class ImageError extends RealError {
    constructor(message) {
      super(message);
      defineProperty(this, 'name', { value: 'ImageError', writable: true, configurable: true });
    }
  }

  class LatLngAlt {
    constructor(lat, lng, alt) {
      this.lat = checkNumber('latitude', lat, -90, 90);
      this.lng = checkNumber('longitude', lng, -180, 180);
      this.alt = checkNumber('altitude', alt === undefined ? 0 : alt, MIN_ALT_M, MAX_ALT_M);
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
  harden([TaskRejectedError, VVMError, MessageError, ImageError, LatLngAlt, LatLng]);

  function sdcEntry(e) {
    return freeze({
      name: e.name,
      description: e.name,
      kind: e.kind,
      unit: e.unit,
      params: freeze(jsonParse(jsonStringify(e.params || {}))),
    });
  }

  // `previousStorage`: the storage the last run of this context ended with, or null.
  function newRun(input, previousStorage) {
    const state = {
      clockMs: input.startMs,
      random: null,
    };
    let effectsApplied = input.effectsApplied;
    const limits = input.limits;
    const signature = runSignature(input);
    let suspended = false;
    let pending = null;
    let fatal = null;
    const effects = [];
    let effectSeq = 0;
    let cursor = 0;
    let startCursor = 0; // where this step's reading of the journal began
    let resumed = false; // this step resumed the program where it waited (no replay)
    let requestSeq = 0;
    let tasksRequested = 0;
    let messagesSent = 0;
    let storageChars = 0; // UTF-8 bytes of the keys and JSON texts stored
    let allocated = 0; // bytes of ArrayBuffers and typed arrays made by this run
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
      fatal = { kind: kind, message: message, quota: quota === undefined ? null : quota, at: callSite() };
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
    // `request` is what the program asks for (undefined for the later parts of a batch, which
    // are not compared); `kinds` the kinds of answer it may have.
    function expect(q, request, kinds) {
      const entry = journal[cursor];
      if (entry.q !== q || kinds.indexOf(entry.k) < 0 ||
          (request !== undefined && entry.r !== undefined && !entry.answers(request))) {
        stop('failed', 'non-determinism: on replay the program made request #' + (q + 1) + ' ' +
          (request === undefined ? undefined : jsonStringify(request)) +
          ' but its journal holds ' + (entry.r === undefined ? jsonStringify(entry.k) : entry.r) +
          ' there; a VV must decide only from what the VVM-API gave it');
      }
      cursor++;
      state.clockMs = entry.t;
      return entry;
    }

    // The two calls that wait for the outside world, as generators: where the call has no
    // answer yet they set the pending request, mark the run suspended and yield. Called from
    // the program as written (`execute`, `executeAll`), the yield becomes SUSPEND, which ends
    // the run (replay mode); at a call site the platform turned into `yield*` (see
    // instrument.py), the program itself stays suspended there until the next step resumes it.
    function* executeSteps(task, callback) {
      allowed('task.execute');
      const request = normalizeTask(task, 'VV.task.execute(task): task');
      if (callback !== undefined && callback !== null && typeof callback !== 'function') {
        throw new TypeError('VV.task.execute(task, callback): callback must be a function');
      }
      countTasks(1);
      const q = requestSeq++;
      while (cursor >= journal.length) {
        pending = { kind: 'task', q: q, r: jsonStringify(request), tasks: [request], at: callSite() };
        suspended = true;
        yield PARK;
      }
      const entry = expect(q, request, TASK_ANSWERS);
      if (entry.k === 'reject') throw new TaskRejectedError(entry.message);
      const data = entry.freshData();
      if (typeof callback === 'function') callback(data);
      return data;
    }

    function* executeAllSteps(tasks, callback) {
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
      let first = true;
      let remaining = requests.length;
      let at = null;
      while (remaining > 0) {
        while (cursor >= journal.length) {
          const open = [];
          for (let i = 0; i < requests.length; i++) if (results[i] === undefined) push(open, i);
          if (at === null) at = callSite();
          pending = { kind: 'batch', q: q, r: first ? jsonStringify(requests) : null, tasks: requests, open: open, at: at };
          suspended = true;
          yield PARK;
        }
        const entry = expect(q, first ? requests : undefined, first ? FIRST_PART_ANSWERS : PART_ANSWERS);
        first = false;
        if (entry.k === 'reject') throw new TaskRejectedError(entry.message);
        const i = entry.i;
        if (typeof i !== 'number' || i < 0 || i >= requests.length || results[i] !== undefined) {
          stop('failed', 'non-determinism: the journal answers part ' + i + ' of a batch of ' + requests.length + ' twice or out of range');
        }
        const data = entry.freshData();
        results[i] = data;
        remaining--;
        if (typeof callback === 'function') callback(data, i);
      }
      return results;
    }

    function settle(steps) {
      const r = reflectApply(generatorNext, steps, []);
      if (!r.done) halt(); // suspended at the call
      return r.value;
    }

    function execute(task, callback) {
      return settle(executeSteps(task, callback));
    }

    function executeAll(tasks, callback) {
      return settle(executeAllSteps(tasks, callback));
    }

    // A call the host answers at once (VV.message.send, VV.image.*), waiting as `execute`
    // does: `args` as checked here are what the host gets (PendingRequest.args) and, with
    // `op`, the request the journal's answer must be for. Its answer is the call's value (a
    // copy of its own) or the error the host found, thrown as MessageError or ImageError.
    function* callSteps(op, args) {
      const q = requestSeq++;
      const request = { op: op, args: args };
      let at = null;
      while (cursor >= journal.length) {
        if (at === null) at = callSite();
        pending = { kind: 'call', q: q, r: jsonStringify(request), tasks: [], op: op, args: args, at: at };
        suspended = true;
        yield PARK;
      }
      const entry = expect(q, request, CALL_ANSWERS);
      if (entry.k === 'err') {
        if (entry.name === 'ImageError') throw new ImageError(entry.message);
        if (entry.name === 'MessageError') throw new MessageError(entry.message);
        throw new VVMError(op + ': ' + entry.message);
      }
      return entry.freshData();
    }

    function* sendSteps(to, value) {
      allowed('message.send');
      const where = 'VV.message.send(to, value)';
      if (typeof to !== 'string' || to.length === 0) {
        throw new TypeError(where + ': to must be the name or the id of a VV (a non-empty string), got ' + describe(to));
      }
      const text = storableText(value, 'sent', where);
      // No VV has such a name (the host would say the same, in the same words).
      if (to.length > MAX_NAME || !plainString(to)) {
        throw new MessageError(where + ': no VV ' + jsonStringify(to) + ' of yours to send to');
      }
      const bytes = utf8Bytes(text);
      if (bytes > limits.messageBytes) {
        throw new MessageError(where + ': the value is ' + bytes + ' bytes of JSON, more than the ' +
          limits.messageBytes + ' allowed (quota: message bytes)');
      }
      if (messagesSent >= limits.maxMessages) {
        throw new MessageError(where + ': this VV has sent ' + messagesSent + ' messages, as many as it may (quota: messages per VV)');
      }
      const sent = yield* callSteps('message.send', { to: to, value: text });
      messagesSent++;
      return sent;
    }

    // A message, or null when none came within `timeoutS` seconds: the host answers when one
    // is there or the time is up.
    function* receiveSteps(timeoutS) {
      allowed('message.receive');
      const timeout = checkNumber('VV.message.receive(timeoutS): timeoutS', timeoutS, 0, MAX_TIMEOUT_S);
      const q = requestSeq++;
      const request = { op: 'message.receive', timeoutS: timeout };
      let at = null;
      while (cursor >= journal.length) {
        if (at === null) at = callSite();
        pending = { kind: 'message', q: q, r: jsonStringify(request), tasks: [], timeout_s: timeout, at: at };
        suspended = true;
        yield PARK;
      }
      return expect(q, request, MESSAGE_ANSWERS).freshData();
    }

    // The picture's image reference; the host refuses one the VV never received.
    function pictureRef(picture, where) {
      const image = picture !== null && typeof picture === 'object' ? picture.image : undefined;
      if (typeof image !== 'string' || image.length === 0 || image.length > MAX_PICTURE_REF || !plainString(image)) {
        throw new TypeError(where + ': picture must be a picture (a camera reading, or what VV.image.crop or VV.image.resize returned), got ' + describe(picture));
      }
      return image;
    }

    // What of the picture crop and resize copy into theirs: its sensor, time and position.
    function pictureSource(picture, where) {
      const source = {};
      for (let i = 0; i < PICTURE_SOURCE_KEYS.length; i++) {
        const key = PICTURE_SOURCE_KEYS[i];
        const value = picture[key];
        if (value !== undefined) source[key] = jsonParse(storableText(value, 'copied', where + ': picture.' + key));
      }
      return source;
    }

    function checkRegion(region, where) {
      if (region === null || typeof region !== 'object' || isArray(region)) {
        throw new TypeError(where + ': region must be an object {x, y, width, height}, got ' + describe(region));
      }
      return {
        x: checkInteger(where + ': region.x', region.x, 0),
        y: checkInteger(where + ': region.y', region.y, 0),
        width: checkInteger(where + ': region.width', region.width, 1),
        height: checkInteger(where + ': region.height', region.height, 1),
      };
    }

    function checkRanges(ranges, where) {
      if (ranges === null || typeof ranges !== 'object' || isArray(ranges)) {
        throw new TypeError(where + ': ranges must be an object such as {r: [min, max], g: [min, max], b: [min, max]}, got ' + describe(ranges));
      }
      const keys = objectKeys(ranges);
      if (keys.length === 0) throw new TypeError(where + ': ranges must give at least one of r, g, b');
      for (let i = 0; i < keys.length; i++) {
        if (CHANNELS.indexOf(keys[i]) < 0) {
          throw new TypeError(where + ': ranges.' + keys[i] + ' is not a channel (ranges may give r, g and b)');
        }
      }
      const checked = {};
      for (let i = 0; i < CHANNELS.length; i++) {
        const c = CHANNELS[i];
        if (keys.indexOf(c) < 0) continue;
        const range = ranges[c];
        if (!isArray(range) || range.length !== 2) {
          throw new TypeError(where + ': ranges.' + c + ' must be [min, max], got ' + describe(range));
        }
        const lo = checkInteger(where + ': ranges.' + c + '[0]', range[0], 0, 255);
        const hi = checkInteger(where + ': ranges.' + c + '[1]', range[1], 0, 255);
        if (lo > hi) {
          throw new RangeError(where + ': ranges.' + c + ' is [' + lo + ', ' + hi + ']: its min is above its max');
        }
        checked[c] = [lo, hi];
      }
      return checked;
    }

    function optional(value) {
      return value === undefined || value === null;
    }

    function* statsSteps(picture, region) {
      allowed('image.stats');
      const image = pictureRef(picture, 'VV.image.stats(picture)');
      const area = optional(region) ? null : checkRegion(region, 'VV.image.stats(picture, region)');
      return yield* callSteps('image.stats', { picture: image, region: area });
    }

    function* fractionSteps(picture, ranges, region) {
      allowed('image.fraction');
      const where = optional(region) ? 'VV.image.fraction(picture, ranges)' : 'VV.image.fraction(picture, ranges, region)';
      const image = pictureRef(picture, where);
      const checked = checkRanges(ranges, where);
      const area = optional(region) ? null : checkRegion(region, where);
      return yield* callSteps('image.fraction', { picture: image, ranges: checked, region: area });
    }

    function* cropSteps(picture, region) {
      allowed('image.crop');
      const where = 'VV.image.crop(picture, region)';
      const image = pictureRef(picture, where);
      const area = checkRegion(region, where);
      return yield* callSteps('image.crop', { picture: image, region: area, source: pictureSource(picture, where) });
    }

    function* resizeSteps(picture, width, height) {
      allowed('image.resize');
      const where = 'VV.image.resize(picture, width, height)';
      const image = pictureRef(picture, where);
      const w = checkInteger(where + ': width', width, 1, MAX_RESIZE);
      const h = checkInteger(where + ': height', height, 1, MAX_RESIZE);
      return yield* callSteps('image.resize', { picture: image, width: w, height: h, source: pictureSource(picture, where) });
    }

    const waiting = freeze({
      'message.send': sendSteps,
      'message.receive': receiveSteps,
      'image.stats': statsSteps,
      'image.fraction': fractionSteps,
      'image.crop': cropSteps,
      'image.resize': resizeSteps,
    });

    function checkKey(key, where) {
      if (typeof key !== 'string' || key.length === 0 || key.length > MAX_KEY) {
        throw new TypeError(where + ': the key must be a string of 1 to ' + MAX_KEY + ' characters, got ' + describe(key));
      }
      if (!reflectApply(stringIsWellFormed, key, [])) {
        throw new RangeError(where + ': the key ' + jsonStringify(key) + ' holds a lone surrogate (half of a UTF-16 pair): a key must be valid Unicode');
      }
      if (reflectApply(stringIndexOf, key, ['\u0000']) >= 0) {
        throw new RangeError(where + ': the key ' + jsonStringify(key) + ' holds the character U+0000, which cannot be stored');
      }
    }

    function store(key, value) {
      allowed('storage.store');
      checkKey(key, 'VV.storage.store(key, value)');
      const text = storableText(value, 'stored', 'VV.storage.store', key);
      const old = reflectApply(mapGet, storage, [key]);
      const bytes = utf8Bytes(key) + utf8Bytes(text);
      const used = storageChars - (old === undefined ? 0 : utf8Bytes(key) + utf8Bytes(old)) + bytes;
      // The pictures the VV made (VV.image.crop, resize) take their share of the quota.
      const pictures = limits.pictureBytes || 0;
      if (effectSeq >= effectsApplied && used + pictures > limits.storageBytes) {
        stop('killed', 'storing ' + jsonStringify(key) + ' would use ' + used + ' bytes of storage' +
          (pictures ? ' and its pictures ' + pictures + ' more' : '') + ', more than the ' +
          limits.storageBytes + ' allowed (quota: storage bytes)', 'storage');
      }
      storageChars = used;
      // A replayed write usually stores the text the last run ended with under the key: keep
      // that string. Equal strings are indistinguishable to a program, and the new one then
      // dies young instead of being copied by the garbage collections of the run (for
      // thousands of replayed writes, a good part of its time).
      const last = previousStorage === null ? undefined : reflectApply(mapGet, previousStorage, [key]);
      reflectApply(mapSet, storage, [key, last === text ? last : text]);
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
      storageChars -= utf8Bytes(key) + utf8Bytes(old);
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

    // A line as the platform can store it: cut at a code point, a lone surrogate or U+0000
    // shown as U+FFFD.
    function logLine(args) {
      let line = '';
      for (let i = 0; i < args.length; i++) line += (i > 0 ? ' ' : '') + text(args[i]);
      if (line.length > MAX_LINE) {
        const c = line.charCodeAt(MAX_LINE - 1);
        const end = c >= 0xd800 && c <= 0xdbff ? MAX_LINE - 1 : MAX_LINE;
        line = reflectApply(stringSlice, line, [0, end]) + '…';
      }
      line = reflectApply(stringToWellFormed, line, []);
      if (reflectApply(stringIndexOf, line, ['\u0000']) >= 0) line = reflectApply(stringReplaceAll, line, ['\u0000', '\ufffd']);
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
      message: freeze({
        send: function send(to, value) { return settle(sendSteps(to, value)); },
        receive: function receive(timeoutS) { return settle(receiveSteps(timeoutS)); },
      }),
      image: freeze({
        stats: function stats(picture, region) { return settle(statsSteps(picture, region)); },
        fraction: function fraction(picture, ranges, region) { return settle(fractionSteps(picture, ranges, region)); },
        crop: function crop(picture, region) { return settle(cropSteps(picture, region)); },
        resize: function resize(picture, width, height) { return settle(resizeSteps(picture, width, height)); },
      }),
      log: function log(...args) { allowed('log'); logLine(args); },
      errors: freeze({ TaskRejectedError: TaskRejectedError, VVMError: VVMError, MessageError: MessageError, ImageError: ImageError }),
    });
    const stdOut = freeze({ println: function println(msg) { allowed('log'); logLine([msg]); } });

    state.globals = {
      VV: VV,
      TaskRejectedError: TaskRejectedError,
      MessageError: MessageError,
      ImageError: ImageError,
      logInfo: function logInfo(msg) { allowed('log'); logLine([msg]); },
      getStdOut: function getStdOut() { return stdOut; },
    };
    state.allocate = function (bytes, what) {
      allocated += bytes;
      if (limits.heapBytes !== undefined && allocated > limits.heapBytes) {
        stop('killed', 'the VV made more than ' + mathFloor(limits.heapBytes / 1048576) +
          ' MB of ArrayBuffers and typed arrays (' + what + '; quota: V8 heap)', 'heap');
      }
    };
    state.executeSteps = executeSteps;
    state.executeAllSteps = executeAllSteps;
    state.waiting = waiting;
    state.rethrow = function (e) { if (e === SUSPEND || suspended) throw SUSPEND; };
    state.isSuspended = function () { return suspended; };
    state.storage = storage;
    // Suspended at a call without an answer, and not stopped by a quota or non-determinism.
    state.isPending = function () { return pending !== null && fatal === null; };
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
        answersRead: cursor - startCursor,
        replayed: !resumed,
        journalLength: journal.length,
        requests: requestSeq,
        storageBytes: storageChars,
        tainted: tainted,
      });
    };

    // A program the platform compiled as a generator runs as one: it stays suspended (parked)
    // at a `yield*` call site between steps, and the next step resumes it there instead of
    // replaying, when nothing the replay would see has changed: the same VV and limits, and
    // every effect of the run applied by the host (else the host lost some, and a new run
    // reports them again). A VV that comes back after steps on another host has more
    // effects applied than this run made: resumed, the program reads the answers of those
    // steps from the journal, as a replay would, and does their effects again unreported
    // (`effect`), then goes on with the new work.
    let steps = null;
    let parked = false;
    state.isParked = function () { return parked; };
    state.canResume = function (next) {
      return parked && fatal === null && next.effectsApplied >= effectSeq && runSignature(next) === signature;
    };
    state.resume = function (next) {
      effects.length = 0;
      effectsApplied = next.effectsApplied;
      pending = null;
      suspended = false;
      startCursor = cursor;
      resumed = true;
    };
    // Runs the program (or resumes it); true when it returned.
    state.drive = function (fn) {
      if (steps === null && getPrototypeOf(fn) !== generatorFunctionPrototype) {
        reflectApply(fn, undefined, []);
        return true;
      }
      if (steps === null) steps = reflectApply(fn, undefined, []);
      parked = false;
      // Not steps.next(): the lookup would go through the program's own (unfrozen) prototype.
      const r = reflectApply(generatorNext, steps, []);
      if (r.done) return true;
      if (r.value !== PARK || pending === null) stop('failed', 'the program yielded outside a VVM-API call');
      parked = true;
      return false;
    };
    return state;
  }

  const generatorFunctionPrototype = getPrototypeOf(function* () {});
  const generatorNext = generatorFunctionPrototype.prototype.next;

  function runSignature(input) {
    return jsonStringify([input.vvId, input.vvName, input.seed, input.startMs, input.limits]);
  }

  // --- what the host calls ----------------------------------------------------------------------
  function appendEntries(json) {
    const entries = jsonParse(json);
    for (let i = 0; i < entries.length; i++) push(journal, new JournalEntry(entries[i]));
  }

  function finish() {
    // A parked program keeps what it put on the global object until it runs again.
    if (!(run !== null && run.isParked()) && !resetGlobals()) tainted = true;
    return run === null ? 'null' : run.outcome();
  }

  // Every host function wants the key this file was installed with: the program can reach
  // `__cpcc_host` through globalThis, but not the key, which lives only in this closure.
  function host(key, what) {
    if (key !== hostKey || running) throw new TypeError(what + ' is for the platform only');
  }

  function constant(name, value) {
    defineProperty(global, name, { value: value, writable: false, enumerable: false, configurable: false });
  }

  // Hooks of the instrumented program: they act on the current run. Frozen (with the
  // prototype of what they make), as everything a program can reach that outlives a run.
  function hook(fn) {
    if (fn.prototype !== undefined) freeze(fn.prototype);
    return freeze(fn);
  }
  constant('__cpcc_rethrow', hook(function (e) { if (run !== null) run.rethrow(e); }));
  constant('__cpcc_suspended', hook(function () { return run !== null && run.isSuspended(); }));
  // The call sites instrument.py turned into `yield*`: the same calls, waiting by yielding.
  constant('__cpcc_execute', hook(function* execute(task, callback) { return yield* run.executeSteps(task, callback); }));
  constant('__cpcc_executeAll', hook(function* executeAll(tasks, callback) { return yield* run.executeAllSteps(tasks, callback); }));
  constant('__cpcc_send', hook(function* send(to, value) { return yield* run.waiting['message.send'](to, value); }));
  constant('__cpcc_receive', hook(function* receive(timeoutS) { return yield* run.waiting['message.receive'](timeoutS); }));
  constant('__cpcc_stats', hook(function* stats(picture, region) { return yield* run.waiting['image.stats'](picture, region); }));
  constant('__cpcc_fraction', hook(function* fraction(picture, ranges, region) { return yield* run.waiting['image.fraction'](picture, ranges, region); }));
  constant('__cpcc_crop', hook(function* crop(picture, region) { return yield* run.waiting['image.crop'](picture, region); }));
  constant('__cpcc_resize', hook(function* resize(picture, width, height) { return yield* run.waiting['image.resize'](picture, width, height); }));

  const hostApi = {
    // The VV's SDC entries: part of its checkpoint, the same for every run.
    setCatalog: function (key, json) { host(key, 'setCatalog'); catalog = jsonParse(json); },
    // The program's function (and the prototype of its generator objects) is frozen: it
    // outlives every run of the context, so nothing may be kept on it from one run to the next.
    setProgram: function (key, fn) {
      host(key, 'setProgram');
      program = hook(fn);
    },
    // Whether a step with the run input `json` would resume where the program waits (and
    // so only run new work) rather than run it from its first line.
    willResume: function (key, json) {
      host(key, 'willResume');
      return run !== null && run.canResume(jsonParse(json));
    },
    // `step`, if it resumes where the program waits (see willResume); else nothing is done
    // (no entry is appended) and 'replay' comes back: the host steps again with the
    // allowance of a replay. One call for the common step instead of two.
    stepIfResumes: function (key, json, entries) {
      host(key, 'stepIfResumes');
      if (run === null || !run.canResume(jsonParse(json))) return 'replay';
      return hostApi.step(key, json, entries);
    },
    // Journal entries as a JSON array (see JournalEntry).
    append: function (key, json) {
      host(key, 'append');
      appendEntries(json);
      return journal.length;
    },
    // One run, after appending the journal entries `entries` (a JSON array) when given. Returns
    // the outcome (see `outcome`) when the program suspends at a call or returns, in the same
    // call, which saves the host a second one. Anything else the program throws (an error, or
    // SUSPEND after a quota or non-determinism stopped it) propagates with the place it was
    // thrown at, and the host asks for the outcome then.
    step: function (key, json, entries) {
      host(key, 'step');
      if (entries !== undefined) appendEntries(entries);
      const input = jsonParse(json);
      if (run !== null && run.canResume(input)) {
        run.resume(input);
      } else {
        const previousStorage = run === null ? null : run.storage;
        run = null;
        if (!resetGlobals()) {
          // What the last run left on the global object (a global it made undeletable, the
          // global object frozen) cannot be cleared: a run here would see it. The host makes
          // a new context and replays there.
          tainted = true;
          return jsonStringify({ status: 'stale', tainted: true });
        }
        run = newRun(input, previousStorage);
        // RegExp's legacy statics (RegExp.input, $1, lastMatch...) outlive a run; a new run
        // starts them as a new context does.
        reflectApply(regExpExec, RESET_MATCH, ['']);
        for (let i = 0; i < RUN_GLOBALS.length; i++) {
          const name = RUN_GLOBALS[i];
          defineProperty(global, name, { value: run.globals[name], writable: false, enumerable: false, configurable: true });
        }
      }
      let returned = false;
      running = true;
      try {
        returned = run.drive(program);
      } finally {
        running = false;
        // A `return` here ends the propagation of SUSPEND; anything else keeps propagating.
        if (returned || run.isPending()) return finish();
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
      return finish();
    },
  };
  for (const name of objectKeys(hostApi)) hook(hostApi[name]);
  constant('__cpcc_host', freeze(hostApi));

  baseline = new RealSet(ownKeys(global));
  for (let i = 0; i < RUN_GLOBALS.length; i++) reflectApply(setAdd, baseline, [RUN_GLOBALS[i]]);
})
