// The live floor plan, an SVG in metres (world x right, y up; SVG y is -y): the cameras with
// their fields of view on the floor, the zones coloured by state, each person a marker with
// id, heading arrow and trail. The view fits itself to the zones, cameras and people.
// Markers carry data-person, data-x, data-y (metres) so their positions can be read. Each id
// has its colour (colours.js, as in 3D and the camera pictures); a person with a joint inside
// an energized zone is drawn red (data-danger="true").

import { idColour } from "./colours.js";
import { el, separateLabels, SVG } from "./svg.js";

const MARGIN_M = 0.8;
const LINGER_MS = 2000;

const points = (polygon) => polygon.map(([x, y]) => `${x.toFixed(3)},${(-y).toFixed(3)}`).join(" ");
const finite = (v) => typeof v === "number" && Number.isFinite(v);

export class FloorPlan {
  constructor(svg, info) {
    this.svg = svg;
    this.info = info;
    this.layers = {
      grid: svg.querySelector("#floor-grid"),
      fov: svg.querySelector("#floor-fov"),
      zones: svg.querySelector("#floor-zones"),
      cameras: svg.querySelector("#floor-cameras"),
      trails: svg.querySelector("#floor-trails"),
      people: svg.querySelector("#floor-people"),
    };
    this.cameras = [];
    this.zones = [];
    this.people = [];
    this.markers = new Map(); // person id -> {g, trail}
    this.view = null;
    this.scale = 1;
    this.lastPeopleAt = 0;
  }

  setCameras(cameras) {
    this.cameras = cameras;
    const { fov, cameras: layer } = this.layers;
    fov.replaceChildren();
    layer.replaceChildren();
    for (const cam of cameras) {
      const down = cam.health && cam.health.state === "down";
      if (Array.isArray(cam.floor_fov) && cam.floor_fov.length >= 3) {
        el("polygon", { points: points(cam.floor_fov), class: `fov${down ? " down" : ""}`,
          "data-camera": cam.name }, fov);
      }
      if (!Array.isArray(cam.position)) continue;
      const [x, y] = cam.position;
      const g = el("g", { class: `camera${down ? " down" : ""}`, "data-camera": cam.name,
        transform: `translate(${x.toFixed(3)},${(-y).toFixed(3)})` }, layer);
      const yaw = finite(cam.yaw_deg) ? cam.yaw_deg : 0;
      const body = el("g", { class: "body" }, g);
      this.scaleBody(body);
      el("path", { d: "M 0.22 0 L -0.14 0.13 L -0.14 -0.13 Z", class: "camera-body",
        transform: `rotate(${(-yaw).toFixed(1)})` }, body);
      const label = el("text", { class: "camera-label", x: 0, y: 0.42 }, body);
      label.textContent = cam.name;
    }
    this.fit();
  }

  /** Health only (the live channel's cameras message): marks cameras down or up again. */
  setHealth(byName) {
    for (const node of this.svg.querySelectorAll("[data-camera]")) {
      const health = byName.get(node.dataset.camera);
      if (health) node.classList.toggle("down", health.state === "down");
    }
  }

  setZones(zones) {
    this.zones = zones;
    const layer = this.layers.zones;
    const seen = new Set();
    for (const zone of zones) {
      seen.add(zone.name);
      let g = layer.querySelector(`g[data-zone="${CSS.escape(zone.name)}"]`);
      if (!g) {
        g = el("g", { "data-zone": zone.name }, layer);
        el("polygon", { class: "zone-shape" }, g);
        el("text", { class: "zone-label" }, g);
      }
      const state = zone.state || "free";
      const power = zone.power && zone.power.state; // live, dead, unknown (from its breakers)
      g.setAttribute("class", `zone zone-${state} kind-${zone.kind || "zone"}${power ? ` power-${power}` : ""}`);
      g.dataset.state = state;
      if (power) g.dataset.power = power;
      else delete g.dataset.power;
      g.dataset.occupants = (zone.occupants || []).join(",");
      const shape = g.querySelector("polygon");
      shape.setAttribute("points", points(zone.polygon));
      const label = g.querySelector("text");
      const who = (zone.occupants || []).length ? ` (${zone.occupants.join(", ")})` : "";
      const since = zone.power && zone.power.since ? ` since ${new Date(zone.power.since * 1000).toLocaleTimeString([], { hour12: false })}` : "";
      const off = zone.enabled === false ? " [switched off]" : "";
      label.textContent = `${zone.name}${off}${power && power !== "live" ? ` [${power}]` : ""}${who}`;
      shape.replaceChildren();
      if (power) {
        const title = document.createElementNS(SVG, "title");
        title.textContent = `${power}${since}: ${zone.power.source || ""}${zone.power.reason ? ` (${zone.power.reason})` : ""}`;
        shape.appendChild(title);
      }
    }
    for (const g of [...layer.children]) if (!seen.has(g.dataset.zone)) g.remove();
    if (!this.fit()) this.placeLabels();
  }

  /** Each zone's label inside the zone's top edge (a zone within another keeps its label
   * apart), or below its bottom edge when the zone is narrower than its label; then labels
   * that would overlap moved apart, each moved one tied to its zone by a leader line. */
  placeLabels() {
    const labels = [];
    for (const zone of this.zones) {
      const g = this.layers.zones.querySelector(`g[data-zone="${CSS.escape(zone.name)}"]`);
      if (!g || !Array.isArray(zone.polygon) || !zone.polygon.length) continue;
      const label = g.querySelector("text");
      const [cx] = centroid(zone.polygon);
      const ys = zone.polygon.map((p) => p[1]);
      const xs = zone.polygon.map((p) => p[0]);
      let width = 0;
      try {
        width = label.getComputedTextLength();
      } catch {
        width = 0; // not laid out (the plan hidden): inside
      }
      const outside = width > Math.max(...xs) - Math.min(...xs);
      label.classList.toggle("outside", outside);
      const y = outside ? -Math.min(...ys) + 0.06 * this.scale : -Math.max(...ys) + 0.08 * this.scale;
      label.setAttribute("x", cx.toFixed(3));
      label.setAttribute("y", y.toFixed(3));
      labels.push(label);
    }
    separateLabels(labels, 0.02 * this.scale);
  }

  setPeople(body) {
    this.people = body.people || [];
    this.lastPeopleAt = performance.now();
    const seen = new Set();
    for (const person of this.people) {
      if (!Array.isArray(person.position) || !finite(person.position[0])) continue;
      const id = String(person.id);
      seen.add(id);
      let marker = this.markers.get(id);
      if (!marker) marker = this.addMarker(id);
      const [x, y] = person.position;
      const { g, trail, arrow } = marker;
      g.dataset.x = x.toFixed(3);
      g.dataset.y = y.toFixed(3);
      g.setAttribute("transform", `translate(${x.toFixed(3)},${(-y).toFixed(3)})`);
      const inAlarm = inDanger(person, this.zones);
      g.classList.toggle("in-alarm", inAlarm);
      g.dataset.danger = String(inAlarm);
      g.classList.toggle("flagged", (person.flags || []).length > 0);
      if (finite(person.heading_deg)) {
        arrow.setAttribute("transform", `rotate(${(-person.heading_deg).toFixed(1)})`);
        arrow.removeAttribute("visibility");
      } else {
        arrow.setAttribute("visibility", "hidden");
      }
      const track = (person.trail || []).filter((p) => finite(p[0]) && finite(p[1]));
      trail.setAttribute("points", points(track.length ? [...track, [x, y]] : [[x, y]]));
      const extra = [person.posture, ...(person.flags || [])].filter(Boolean).join(" ");
      marker.label.textContent = extra ? `${id} ${extra}` : id;
    }
    // a person missing from a frame or two stays, faded, where last seen: no flicker
    const now = performance.now();
    for (const [id, marker] of this.markers) {
      const missing = !seen.has(id);
      if (!missing) marker.seenAt = now;
      marker.g.classList.toggle("lost", missing);
      marker.trail.classList.toggle("lost", missing);
      if (missing && now - marker.seenAt > LINGER_MS) {
        marker.g.remove();
        marker.trail.remove();
        this.markers.delete(id);
      }
    }
    this.info.textContent = `${seen.size} ${seen.size === 1 ? "person" : "people"} · frame ${body.frame ?? "-"}`;
    this.fit();
  }

  addMarker(id) {
    const trail = el("polyline", { class: "trail", "data-trail": id }, this.layers.trails);
    const g = el("g", { class: "person", "data-person": id }, this.layers.people);
    const body = el("g", { class: "body" }, g);
    this.scaleBody(body);
    const arrow = el("path", { class: "heading", d: "M 0.16 -0.1 L 0.55 0 L 0.16 0.1 Z" }, body);
    el("circle", { class: "person-halo", r: 0.3 }, body);
    const dot = el("circle", { class: "person-dot", r: 0.17 }, body);
    dot.style.setProperty("--id-colour", idColour(id)); // CSSOM: no inline style attribute
    g.dataset.colour = idColour(id);
    const label = el("text", { class: "person-label", x: 0, y: 0.07 }, body);
    const marker = { g, trail, arrow, label, seenAt: performance.now() };
    this.markers.set(id, marker);
    return marker;
  }

  /** The view: zones, camera positions and people, with a margin; changed only when it moves
   * by more than a little, so the plan does not jitter. Whether it changed (the labels then
   * placed again). */
  fit() {
    const xs = [];
    const ys = [];
    const add = (x, y) => {
      if (finite(x) && finite(y)) {
        xs.push(x);
        ys.push(y);
      }
    };
    for (const zone of this.zones) for (const [x, y] of zone.polygon || []) add(x, y);
    for (const cam of this.cameras) if (Array.isArray(cam.position)) add(cam.position[0], cam.position[1]);
    for (const person of this.people) if (Array.isArray(person.position)) add(person.position[0], person.position[1]);
    if (!xs.length) return false;
    let [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
    x0 -= MARGIN_M; x1 += MARGIN_M; y0 -= MARGIN_M; y1 += MARGIN_M;
    const view = [x0, -y1, x1 - x0, y1 - y0];
    const old = this.view;
    const moved = !old || view.some((v, i) => Math.abs(v - old[i]) > 0.25);
    if (!moved) return false;
    this.view = view;
    this.svg.setAttribute("viewBox", view.map((v) => v.toFixed(3)).join(" "));
    // marker bodies and labels are drawn for a 10 m view and scaled with it, so that they
    // keep their size on the screen
    this.scale = Math.max(view[2], view[3]) / 10;
    this.svg.style.setProperty("--unit", this.scale.toFixed(4));
    for (const body of this.svg.querySelectorAll(".body")) this.scaleBody(body);
    this.drawGrid(view);
    this.placeLabels(); // their size follows the scale: placed and kept apart again
    return true;
  }

  scaleBody(body) {
    body.setAttribute("transform", `scale(${this.scale.toFixed(4)})`);
  }

  drawGrid([x, y, w, h]) {
    const grid = this.layers.grid;
    grid.replaceChildren();
    const step = w > 30 || h > 30 ? 5 : 1;
    for (let gx = Math.ceil(x / step) * step; gx <= x + w; gx += step) {
      el("line", { x1: gx, y1: y, x2: gx, y2: y + h, class: gx === 0 ? "axis" : "" }, grid);
    }
    for (let gy = Math.ceil(y / step) * step; gy <= y + h; gy += step) {
      el("line", { x1: x, y1: gy, x2: x + w, y2: gy, class: gy === 0 ? "axis" : "" }, grid);
    }
  }

  /** Seconds since the last people message (the plan says so when it is stale). */
  age() {
    return this.lastPeopleAt ? (performance.now() - this.lastPeopleAt) / 1000 : Infinity;
  }
}

/** Whether the person is in danger: inside an energized zone (a joint in it: the zone's
 * occupants, or the person's own zones), or an occupant of a zone in alarm. */
export function inDanger(person, zones) {
  const mine = new Set(person.zones || []);
  return zones.some((z) => (z.kind === "energized" && (mine.has(z.name) || (z.occupants || []).includes(person.id)))
    || (z.state === "alarm" && (z.occupants || []).includes(person.id)));
}

function centroid(polygon) {
  let sx = 0;
  let sy = 0;
  for (const [x, y] of polygon) {
    sx += x;
    sy += y;
  }
  return [sx / polygon.length, sy / polygon.length];
}
