// A survey split between two VVs that tell each other what they found. Run this one program
// twice, as "survey-west" and "survey-east": each measures temperature and NOx (with a GPS fix)
// at the six points of its half of a grid over both RVs' areas and stores them, sends the other
// VV a summary of its half (the maximum, where it was, and the mean), waits up to 30 minutes
// for the other's summary, stores it next to its own and logs the hottest point of the grid.
var thermometer = VV.sensor.get('Thermometer');
var nox = VV.sensor.get('NOx');
var gps = VV.sensor.get('GPS');

var WAIT_S = 1800;
var HALVES = {
  'survey-west': { lngs: [12.8600, 12.8615, 12.8630], other: 'survey-east' },
  'survey-east': { lngs: [12.8648, 12.8661, 12.8674], other: 'survey-west' }
};
var LATS = [48.1100, 48.1122];

var half = HALVES[VV.name];
if (half === undefined) {
  throw new Error('run this program as "survey-west" or "survey-east", not as "' + VV.name + '"');
}

var tasks = [];
for (var i = 0; i < LATS.length; ++i) {
  for (var j = 0; j < half.lngs.length; ++j) {
    tasks.push({
      type: 'point',
      position: new VV.types.LatLngAlt(LATS[i], half.lngs[j], 40),
      tolerance: 3,
      sensors: [thermometer, nox, gps]
    });
  }
}

// The platform picks the order of the points (and the RV); the readings come back in the
// order of `tasks`.
var readings = VV.task.executeAll(tasks);
var points = [];
for (var k = 0; k < readings.length; ++k) {
  var fix = readings[k][2];
  var point = {
    temperature: readings[k][0].value,
    nox: readings[k][1].value,
    lat: fix.lat,
    lng: fix.lng
  };
  VV.storage.store('point.' + k, point);
  points.push(point);
}

function round2(x) {
  return Math.round(x * 100) / 100;
}

// The largest value of `field` over the points, where it was measured, and the mean.
function summarise(field) {
  var best = points[0];
  var sum = 0;
  for (var k = 0; k < points.length; ++k) {
    if (points[k][field] > best[field]) best = points[k];
    sum += points[k][field];
  }
  return { max: best[field], at: { lat: best.lat, lng: best.lng }, mean: round2(sum / points.length) };
}

var mine = {
  by: VV.name,
  points: points.length,
  temperature: summarise('temperature'),
  nox: summarise('nox')
};
VV.storage.store('summary.' + VV.name, mine);

try {
  VV.message.send(half.other, mine);
} catch (e) {
  if (!(e instanceof MessageError)) throw e;
  VV.log('could not send my summary:', e.message); // the other VV has ended already
}

// Messages from anyone else of the customer (another VV, or the customer's own system over
// the REST API, `from` null) are logged and skipped.
var theirs = null;
while (theirs === null) {
  var message = VV.message.receive(WAIT_S);
  if (message === null) {
    VV.log('no summary from', half.other, 'within', WAIT_S, 's: the hottest point is of my half only');
    break;
  }
  if (message.from === half.other) {
    theirs = message.value;
  } else {
    VV.log('skipped a message from', message.from === null ? 'the REST API' : message.from);
  }
}

var hottest = { temperature: mine.temperature.max, at: mine.temperature.at, by: VV.name };
if (theirs !== null) {
  VV.storage.store('summary.' + half.other, theirs);
  // On a tie both VVs name the same one: the first of the two names.
  var hotter = theirs.temperature.max > hottest.temperature ||
    (theirs.temperature.max === hottest.temperature && half.other < VV.name);
  if (hotter) {
    hottest = { temperature: theirs.temperature.max, at: theirs.temperature.at, by: half.other };
  }
}
VV.storage.store('hottest', hottest);
VV.log('hottest point:', hottest.temperature, '°C at', hottest.at.lat + ',', hottest.at.lng,
  '(measured by ' + hottest.by + ')');
