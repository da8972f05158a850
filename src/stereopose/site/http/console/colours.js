// One colour per person id, the same as the camera pictures, the alarm clips and the report
// draw it (stereopose.viz.colours, kept equal by a test). Red is never an id's colour: it is the
// alarm's, and a person inside an energized zone is drawn in it.

export const ID_COLOURS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2",
  "#17becf", "#bcbd22", "#7f7f7f"];
export const ALARM_COLOUR = "#ff3b3b";

export const idColour = (id) => ID_COLOURS[Math.abs(Math.trunc(Number(id)) || 0) % ID_COLOURS.length];
