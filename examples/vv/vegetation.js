// Where is the vegetation? Photograph a 3 x 3 grid from 60 m, measure how much of the ground
// in each picture is green (fields of green crops, hedges, forest), then go back to the three
// greenest spots at 20 m, look closer at the ground just ahead and store what it is like.
// The paper's RVs carry a camera that looks ahead (a belly camera would look straight down).
var camera = VV.sensor.get('Camera 640x480');

// Green: a strong green channel with less red and little blue. Yellow fields, bare soil,
// roads, water and sky fall outside.
var GREEN = { r: [0, 130], g: [60, 255], b: [0, 90] };
var BEST = 3;
var LATS = [48.1097, 48.1113, 48.1129];
var LNGS = [12.8606, 12.8628, 12.8652];

// The camera looks ahead, a little down: the top of a picture is sky and the haze of the
// distance, its lower half the ground ahead (from 60 m: about 90 to 570 m ahead).
function ground(picture) {
  var top = Math.floor(picture.height / 2);
  return { x: 0, y: top, width: picture.width, height: picture.height - top };
}

// The bottom centre of a picture: the ground closest ahead of the camera (from 20 m: about
// 30 to 50 m ahead).
function justAhead(picture) {
  var width = Math.floor(picture.width / 3);
  var height = Math.floor(picture.height / 4);
  return { x: Math.floor((picture.width - width) / 2), y: picture.height - height, width: width, height: height };
}

function photograph(lat, lng, alt) {
  return { type: 'point', position: new VV.types.LatLngAlt(lat, lng, alt), tolerance: 3, sensors: [camera] };
}

var tasks = [];
for (var i = 0; i < LATS.length; ++i) {
  for (var j = 0; j < LNGS.length; ++j) tasks.push(photograph(LATS[i], LNGS[j], 60));
}
var pictures = VV.task.executeAll(tasks);

var grid = [];
for (var k = 0; k < pictures.length; ++k) {
  var picture = pictures[k][0];
  var green = VV.image.fraction(picture, GREEN, ground(picture));
  grid.push({ index: k, position: tasks[k].position, green: green });
  VV.storage.store('grid.' + k, { position: tasks[k].position, green: green, picture: picture });
}

// The greenest first; of two equally green spots the one earlier in the grid.
grid.sort(function (a, b) { return b.green - a.green || a.index - b.index; });
var best = grid.slice(0, BEST);
VV.storage.store('greenest', best.map(function (spot) { return spot.index; }));
VV.log('greenest from 60 m:', best.map(function (spot) {
  return 'grid.' + spot.index + ' ' + Math.round(spot.green * 100) + ' %';
}).join(', '));

for (var n = 0; n < best.length; ++n) {
  var spot = best[n];
  var close = VV.task.execute(photograph(spot.position.lat, spot.position.lng, 20))[0];
  var detail = VV.image.crop(close, justAhead(close));
  var closeup = {
    position: close.position,
    greenFrom60m: spot.green,
    green: VV.image.fraction(detail, GREEN),
    stats: VV.image.stats(detail),
    picture: close,
    detail: detail,
    thumbnail: VV.image.resize(close, 160, 120)
  };
  VV.storage.store('closeup.' + spot.index, closeup);
  VV.log('grid.' + spot.index + ' from 20 m:', Math.round(closeup.green * 100),
    '% green just ahead, mean colour', closeup.stats.mean.r, closeup.stats.mean.g, closeup.stats.mean.b);
}
