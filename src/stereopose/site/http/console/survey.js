// The Site tab's surveyed points: the rig placed from points of known site coordinates while
// the service runs (GET/PUT /api/survey, POST /api/survey/solve and /accept). An admin types or
// pastes the points' coordinates (one per line: name x y z, metres), chooses a point and clicks
// it in the camera's picture above (each camera in turn); Save writes the points file, Solve
// places every camera from it (each camera's error and how far it would move; each click's
// residual beside its mark), Accept applies the new rig at the next step. Everyone sees them.

import * as api from "./api.js";
import { byId } from "./dom.js";
import { el } from "./svg.js";


function cell(row, content) {
  const td = document.createElement("td");
  td.textContent = content;
  row.appendChild(td);
}

export function parsePoints(textValue) {
  // name x y z per line (spaces, tabs or commas); a blank line or one starting # is skipped
  const points = {};
  const errors = [];
  textValue.split("\n").forEach((line, k) => {
    const words = line.trim().split(/[\s,;]+/).filter(Boolean);
    if (!words.length || words[0].startsWith("#")) return;
    const xyz = words.slice(1).map(Number);
    if (words.length !== 4 || !xyz.every(Number.isFinite)) errors.push(`line ${k + 1}: name x y z`);
    else points[words[0]] = xyz;
  });
  return { points, errors };
}

export class SurveyPanel {
  constructor(editor) {
    this.editor = editor; // the Site tab: its camera view, where the points are clicked
    this.points = {};
    this.cameras = {};
    this.solved = null;
    this.admin = false;
    byId("survey-points").addEventListener("input", () => this.fromText());
    byId("survey-save").addEventListener("click", () => this.save());
    byId("survey-solve").addEventListener("click", () => this.solve());
    byId("survey-accept").addEventListener("click", () => this.accept());
  }

  setRole(role) {
    this.admin = role === "admin";
    byId("survey-points").readOnly = !this.admin;
  }

  async load() {
    try {
      const got = await api.call("/api/survey");
      this.points = got.points;
      this.cameras = got.cameras;
      this.solved = got.solved;
      byId("survey-error").textContent = "";
    } catch (e) {
      byId("survey-error").textContent = e.status === 503 ? "" : `${e.detail || e.message}`;
      return;
    }
    byId("survey-points").value = Object.entries(this.points)
      .map(([name, xyz]) => `${name} ${xyz.join(" ")}`).join("\n");
    this.renderPoints();
    this.renderResult();
  }

  fromText() {
    const { points, errors } = parsePoints(byId("survey-points").value);
    byId("survey-error").textContent = errors.join("; ");
    if (errors.length) return;
    this.points = points;
    this.renderPoints();
    this.editor.drawViews();
  }

  renderPoints() {
    const select = byId("survey-point");
    const chosen = select.value;
    select.replaceChildren(...Object.keys(this.points).map((name) => {
      const option = document.createElement("option");
      option.value = name;
      option.textContent = name;
      return option;
    }));
    if (chosen in this.points) select.value = chosen;
  }

  // A click in the camera's picture (x, y: fractions of it): the chosen point seen there.
  click(camera, x, y, size) {
    const point = byId("survey-point").value;
    if (!this.admin || !point || !(point in this.points)) return false;
    (this.cameras[camera] ||= {})[point] = [x * size[0], y * size[1]];
    const names = Object.keys(this.points);
    byId("survey-point").value = names[(names.indexOf(point) + 1) % names.length];
    byId("survey-info").textContent = `${point} clicked in ${camera}: not saved`;
    this.editor.drawViews();
    return true;
  }

  // The points clicked in camera `cam` as marks on its picture, with their residuals once solved.
  draw(svg, cam) {
    const residuals = (this.solved && this.solved.residuals_px[cam.name]) || {};
    for (const [name, [u, v]] of Object.entries(this.cameras[cam.name] || {})) {
      if (!(name in this.points)) continue;
      const g = el("g", { class: "survey-mark", "data-point": name }, svg);
      const [x, y] = [u / cam.size[0], v / cam.size[1]];
      el("circle", { cx: x, cy: y, r: 0.006 }, g);
      const label = el("text", { x: x + 0.008, y: y - 0.008 }, g);
      const r = residuals[name];
      label.textContent = r === undefined ? name : `${name} ${r === null ? "?" : r.toFixed(1)} px`;
    }
  }

  body() {
    const cameras = {};
    for (const [camera, clicks] of Object.entries(this.cameras)) {
      const kept = Object.fromEntries(Object.entries(clicks).filter(([name]) => name in this.points));
      if (Object.keys(kept).length) cameras[camera] = kept;
    }
    return { points: this.points, cameras };
  }

  async save() {
    byId("survey-error").textContent = "";
    try {
      await api.call("/api/survey", { method: "PUT", body: this.body() });
      byId("survey-info").textContent = "saved";
      this.solved = null;
      this.renderResult();
    } catch (e) {
      byId("survey-error").textContent = `${e.detail || e.message}`;
    }
  }

  async solve() {
    byId("survey-error").textContent = "";
    try {
      // a long solve runs on the server's own thread: asked after until it is done
      let got = await api.call("/api/survey/solve", { method: "POST" });
      while (got && got.state === "solving") {
        byId("survey-info").textContent = "solving";
        await new Promise((done) => setTimeout(done, 500));
        got = await api.call("/api/survey/solve");
      }
      this.solved = got;
      byId("survey-info").textContent = "solved: accept to apply it";
    } catch (e) {
      this.solved = null;
      byId("survey-error").textContent = `${e.detail || e.message}`;
    }
    this.renderResult();
    this.editor.drawViews();
  }

  async accept() {
    try {
      const done = await api.call("/api/survey/accept", { method: "POST" });
      byId("survey-info").textContent = `the new rig (${done.cameras.join(", ")}) is applied at the next step`;
      this.solved = null;
      this.renderResult();
    } catch (e) {
      byId("survey-error").textContent = `${e.detail || e.message}`;
    }
  }

  renderResult() {
    const table = byId("survey-result");
    table.replaceChildren();
    const s = this.solved;
    byId("survey-accept").disabled = !s || s.unplaced.length > 0;
    if (!s) return;
    const head = table.insertRow();
    for (const h of ["camera", "error px", "moves m", "turns °"]) cell(head, h);
    for (const [name, c] of Object.entries(s.cameras)) {
      const row = table.insertRow();
      row.dataset.camera = name;
      cell(row, name);
      cell(row, c.rms_px.toFixed(2));
      cell(row, c.moved_m === null ? "-" : c.moved_m.toFixed(3));
      cell(row, c.turned_deg === null ? "-" : c.turned_deg.toFixed(2));
    }
    const notes = [...s.warnings, ...s.left_out.map((o) => `${o.point} in ${o.camera} left out (${o.px} px)`)];
    if (s.unplaced.length) notes.push(`not placed: ${s.unplaced.join(", ")} (click the points there too)`);
    byId("survey-notes").textContent = notes.join("; ");
  }
}
