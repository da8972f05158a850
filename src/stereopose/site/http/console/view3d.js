// The live 3D view with plotly.js (the bundle served at /console/plotly.min.js, loaded the
// first time the view is opened): each person's skeleton, the zones as prisms, the cameras.
// Redrawn with Plotly.react at a modest rate while the view is shown.

import { ALARM_COLOUR, idColour } from "./colours.js";
import { inDanger } from "./floorplan.js";

const PERIOD_MS = 500;
// COCO-17 limbs (joint indices)
const LIMBS = [
  [0, 1], [0, 2], [1, 3], [2, 4], [5, 6], [5, 7], [7, 9], [6, 8], [8, 10], [5, 11], [6, 12],
  [11, 12], [11, 13], [13, 15], [12, 14], [14, 16],
];
const ZONE_COLOURS = { free: "#4caf50", occupied: "#ffb020", alarm: "#ff3b3b" };

let loading = null;

export function loadPlotly() {
  if (window.Plotly) return Promise.resolve(window.Plotly);
  if (!loading) {
    loading = new Promise((resolve, reject) => {
      const script = document.createElement("script");
      script.src = "/console/plotly.min.js";
      script.addEventListener("load", () => resolve(window.Plotly));
      script.addEventListener("error", () => reject(new Error("plotly.min.js did not load")));
      document.head.appendChild(script);
    });
  }
  return loading;
}

// each id its colour (as on the plan and in the camera pictures); a person in danger red
const colour = (person, zones) => (inDanger(person, zones) ? ALARM_COLOUR : idColour(person.id));

/** A name as plotly's SVG text (legend, hover, annotations): plotly reads `<b>`, `<a href>`,
 * `<span style>` ... in it as markup (links, and style attributes the page's CSP refuses) and
 * decodes &amp; &lt; &gt; (only a few entities: no &quot;) once, so these three show as typed. */
export const plain = (value) => String(value ?? "").replace(/&/g, "&amp;").replace(/</g, "&lt;")
  .replace(/>/g, "&gt;");

/** A person's skeleton as one trace of line segments (the live view's and the replay's). */
export function skeletonTrace(person, color, width = 6, meta = {}) {
  const x = [];
  const y = [];
  const z = [];
  const joints = person.joints || [];
  for (const [a, b] of LIMBS) {
    const p = joints[a];
    const q = joints[b];
    if (!p || !q) continue;
    x.push(p[0], q[0], null);
    y.push(p[1], q[1], null);
    z.push(p[2], q[2], null);
  }
  return {
    type: "scatter3d", mode: "lines", name: `id ${plain(person.id)}`, x, y, z,
    line: { color, width }, hoverinfo: "name", meta: { person: person.id, ...meta },
  };
}

/** Each person's id above the head, in its colour (`colourOf(person)`). */
export function headsTrace(people, colourOf) {
  const shown = people.filter((p) => p.joints && p.joints[0]);
  return {
    type: "scatter3d", mode: "text+markers", name: "ids", showlegend: false,
    x: shown.map((p) => p.joints[0][0]), y: shown.map((p) => p.joints[0][1]),
    z: shown.map((p) => p.joints[0][2] + 0.25), text: shown.map((p) => String(p.id)), // WebGL text: numbers only
    marker: { size: 3, color: shown.map(colourOf) },
    textfont: { color: "#ffffff", size: 14 }, hoverinfo: "skip",
  };
}

/** The dark 3D layout both views draw in (the operator's camera angle kept across updates). */
export function sceneLayout(annotations = []) {
  return {
    uirevision: "keep",
    paper_bgcolor: "#0d1117", plot_bgcolor: "#0d1117", font: { color: "#c8d3e0" },
    margin: { l: 0, r: 0, t: 0, b: 0 }, showlegend: true,
    legend: { bgcolor: "rgba(0,0,0,0)", x: 0, y: 1 },
    scene: {
      aspectmode: "data", bgcolor: "#0d1117", annotations,
      xaxis: { title: { text: "x (m)" }, gridcolor: "#2a3340", zerolinecolor: "#4a5668" },
      yaxis: { title: { text: "y (m)" }, gridcolor: "#2a3340", zerolinecolor: "#4a5668" },
      zaxis: { title: { text: "z (m)" }, gridcolor: "#2a3340", zerolinecolor: "#4a5668" },
    },
  };
}

function skeleton(person, zones) {
  const danger = inDanger(person, zones);
  return skeletonTrace(person, colour(person, zones), danger ? 10 : 6, { danger });
}

/** A zone's prism: its floor polygon at the bottom and top of its height band, as edges
 * (coloured by its state; `highlight`: drawn thick, a ticket step's target or position). */
export function prism(zone, highlight = false) {
  const [lo, hi] = zone.z || [0, 2];
  const poly = zone.polygon || [];
  const x = [];
  const y = [];
  const z = [];
  for (const level of [lo, hi]) {
    for (const [px, py] of [...poly, poly[0]]) {
      x.push(px);
      y.push(py);
      z.push(level);
    }
    x.push(null);
    y.push(null);
    z.push(null);
  }
  for (const [px, py] of poly) {
    x.push(px, px, null);
    y.push(py, py, null);
    z.push(lo, hi, null);
  }
  const state = zone.state || "free";
  return {
    type: "scatter3d", mode: "lines", name: `${plain(zone.name)} (${plain(state)})`, x, y, z,
    line: { color: highlight ? "#79c0ff" : (ZONE_COLOURS[state] || "#999999"),
      width: highlight || state === "alarm" ? 7 : 3 },
    hoverinfo: "name",
  };
}

// The cameras' names are annotations (SVG text, where escaping holds), not the trace's `text`:
// plotly draws 3D text in WebGL, which reads <b>, <i>, <sub>, <sup> in it and no entity.
function cameraMarkers(cameras) {
  const shown = cameras.filter((c) => Array.isArray(c.position));
  return {
    type: "scatter3d", mode: "markers", name: "cameras",
    x: shown.map((c) => c.position[0]), y: shown.map((c) => c.position[1]),
    z: shown.map((c) => c.position[2]), hovertext: shown.map((c) => plain(c.name)),
    marker: { size: 5, symbol: "diamond",
      color: shown.map((c) => (c.health && c.health.state === "down" ? "#ff3b3b" : "#8ab4ff")) },
    hoverinfo: "text",
  };
}

function cameraLabels(cameras) {
  return cameras.filter((c) => Array.isArray(c.position)).map((c) => ({
    x: c.position[0], y: c.position[1], z: c.position[2], text: plain(c.name),
    showarrow: false, yshift: 12, font: { color: "#c8d3e0", size: 11 },
  }));
}

export class View3D {
  constructor(root, info) {
    this.root = root;
    this.info = info;
    this.people = [];
    this.zones = [];
    this.cameras = [];
    this.timer = null;
    this.dirty = true;
    this.drawing = false;
  }

  setPeople(people) { this.people = people; this.dirty = true; }
  setZones(zones) { this.zones = zones; this.dirty = true; }
  setCameras(cameras) { this.cameras = cameras; this.dirty = true; }

  async show(active) {
    clearInterval(this.timer);
    this.timer = null;
    if (!active) return;
    try {
      await loadPlotly();
    } catch (error) {
      this.info.textContent = String(error.message);
      return;
    }
    this.dirty = true;
    this.draw();
    this.timer = setInterval(() => this.draw(), PERIOD_MS);
  }

  async draw() {
    if (!this.dirty || this.drawing || !window.Plotly) return;
    this.dirty = false;
    this.drawing = true;
    const traces = [
      ...this.zones.map((z) => prism(z)),
      cameraMarkers(this.cameras),
      ...this.people.map((p) => skeleton(p, this.zones)),
      headsTrace(this.people, (p) => colour(p, this.zones)),
    ];
    const layout = sceneLayout(cameraLabels(this.cameras));
    try {
      await window.Plotly.react(this.root, traces, layout, { displayModeBar: false, responsive: true });
      this.info.textContent = `${this.people.length} people`;
    } finally {
      this.drawing = false;
    }
  }
}
