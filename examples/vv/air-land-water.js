// One VV that goes from the air to the land and into the water (examples/scenarios/
// lake-and-fields.json): the air's temperature 30 m over the west field (a copter), the soil's
// on the field (a rover), the lake's at its surface (a boat) and the depth 5 m under it (a
// submarine). No vehicle can do all four, so the platform migrates the VV from one kind of
// vehicle to the next. It stores every reading under its leg's name; a reading says where it was
// taken ("position": lat, lng and alt, which is below 0 under water).
var legs = [
  { name: 'air', at: new VV.types.LatLngAlt(48.1125, 12.8590, 30), sensor: 'Thermometer' },
  { name: 'land', at: new VV.types.LatLngAlt(48.1100, 12.8595, 0), sensor: 'Soil temperature' },
  { name: 'surface', at: new VV.types.LatLngAlt(48.1124, 12.8642, 0), sensor: 'Water temperature' },
  { name: 'underwater', at: new VV.types.LatLngAlt(48.1118, 12.8652, -5), sensor: 'Depth gauge' }
];

for (var n = 0; n < legs.length; ++n) {
  var leg = legs[n];
  VV.task.execute(
    { type: 'point', position: leg.at, tolerance: 2, sensors: [VV.sensor.get(leg.sensor)] },
    function (data) {
      VV.storage.store(n + '.' + leg.name, data[0]);
    }
  );
}
