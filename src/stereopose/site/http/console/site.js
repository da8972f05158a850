// The Site tab: the running site's zones on a plan in metres (world x right, y up), and for an
// admin its editor. A zone is chosen on the plan or in the list; its corners are dragged (they
// snap to a 0.05 m grid and to other zones' corners within 0.15 m); a new zone is drawn by
// clicking its corners; its name, kind, height band, margin or voltage are set in the form.
// Save sends PUT /api/site with the version it was edited from: the service takes it at its
// next step. An error names the zone and key; another admin's change first is a conflict.
// The history lists the versions kept; an earlier one is restored by saving it again.
// Everyone sees the tab; only an admin edits (the API refuses the others anyway).

import * as api from "./api.js";
import { byId, text } from "./dom.js";
import { SiteOutputs } from "./site_outputs.js";
import { SurveyPanel } from "./survey.js";
import { el, separateLabels } from "./svg.js";

const GRID_M = 0.05;
const SNAP_M = 0.15;
const KINDS = ["energized", "restricted", "work_area"];

// the form's field of each key the API's errors name
const FIELDS = {
  name: "site-name", kind: "site-kind", z: "site-z0", margin_m: "site-margin",
  voltage_kv: "site-voltage", distance_table: "site-distance", joints: "site-joints",
  power: "site-power", polygon: "site-points",
};

function fieldError(id, message) {
  const input = byId(id);
  let note = input.parentElement.querySelector(".field-error");
  if (!note) {
    note = text("span", "", "field-error");
    note.setAttribute("role", "alert");
    input.parentElement.appendChild(note);
  }
  note.textContent = message;
  input.classList.toggle("invalid", Boolean(message));
}

const round = (v) => Number((Math.round(v / GRID_M) * GRID_M).toFixed(3));
const pts = (polygon) => polygon.map(([x, y]) => `${x.toFixed(3)},${(-y).toFixed(3)}`).join(" ");

export class SiteEditor {
  constructor() {
    this.svg = byId("site-plan");
    this.version = null;
    this.site = null;
    this.selected = -1;
    this.drawing = null; // the corners of a zone being drawn
    this.admin = false;
    this.dirty = false;
    this.drag = null;
    byId("site-new").addEventListener("click", () => this.startDrawing());
    byId("site-finish").addEventListener("click", () => this.finishDrawing());
    byId("site-delete").addEventListener("click", () => this.deleteZone());
    byId("site-save").addEventListener("click", () => this.save());
    byId("site-reload").addEventListener("click", () => this.load());
    byId("site-form").addEventListener("input", () => this.fromForm());
    this.svg.addEventListener("pointerdown", (e) => this.onDown(e));
    this.svg.addEventListener("pointermove", (e) => this.onMove(e));
    this.svg.addEventListener("pointerup", () => { this.drag = null; });
    this.camera = null;
    this.views = null;
    this.viewTimer = null;
    byId("site-camera").addEventListener("change", (e) => { this.camera = e.target.value; this.drawViews(); });
    byId("site-camera-svg").addEventListener("click", (e) => this.onCameraClick(e));
    // the picture as wide as the column, or zoomed to the camera's own pixels (1:1, 2:1);
    // the camera pixel under the pointer shown while placing
    this.zoom = "fit";
    for (const button of document.querySelectorAll(".site-zoom button")) {
      button.addEventListener("click", () => this.setZoom(button.dataset.zoom));
    }
    byId("site-camera-svg").addEventListener("mousemove", (e) => this.showPixel(e));
    byId("site-camera-svg").addEventListener("mouseleave", () => { byId("site-pixel").textContent = ""; });
    byId("site-camera-img").addEventListener("error", () => { byId("site-camera-img").hidden = true; });
    this.survey = new SurveyPanel(this); // the surveyed points, clicked in the same pictures
    this.outputs = new SiteOutputs(this); // the speakers and signals of the warnings on site
    this.background = null; // the plan's drawing: {points, size} (GET .../placement)
    this.backgroundVersion = 0;
    byId("site-bg-set").addEventListener("click", () => this.setBackground());
    byId("site-bg-remove").addEventListener("click", () => this.removeBackground());
  }

  setRole(role) {
    this.admin = role === "admin";
    for (const node of document.querySelectorAll(".site-admin")) node.hidden = !this.admin;
    this.survey.setRole(role);
  }

  async show(on) {
    clearInterval(this.peopleTimer);
    if (!on) return;
    if (!this.dirty) await this.load();
    this.loadCameras();
    this.peopleTimer = setInterval(() => this.refreshPeople(), 1000);
  }

  async load() {
    const info = byId("site-info");
    try {
      const got = await api.call("/api/site");
      this.version = got.version;
      this.site = got.site;
      this.dirty = false;
      this.selected = Math.min(this.selected, this.zones().length - 1);
      info.textContent = `version ${this.version}`;
      byId("site-error").textContent = "";
    } catch (error) {
      this.site = null;
      info.textContent = error.status === 503 ? "this service has no site file" : `${error.detail || error.message}`;
    }
    try {
      const placed = await api.call("/api/site/background/placement");
      this.background = placed && placed.drawing ? placed : null; // none: the usual state
      this.backgroundVersion += 1;
    } catch {
      this.background = null;
    }
    this.render();
    this.loadHistory();
    this.survey.load();
  }

  zones() {
    return this.site && Array.isArray(this.site.zones) ? this.site.zones : [];
  }

  // -- drawing ------------------------------------------------------------------------------

  render() {
    const zones = this.zones();
    this.svg.replaceChildren();
    const placed = (this.cameras || []).map((c) => c.position).filter(Array.isArray);
    const all = zones.flatMap((z) => z.polygon || [])
      .concat(this.drawing || [], placed, this.outputs.positions());
    const xs = all.map((p) => p[0]);
    const ys = all.map((p) => p[1]);
    const [x0, x1] = xs.length ? [Math.min(...xs) - 1, Math.max(...xs) + 1] : [-5, 5];
    const [y0, y1] = ys.length ? [Math.min(...ys) - 1, Math.max(...ys) + 1] : [-5, 5];
    this.svg.setAttribute("viewBox", `${x0} ${-y1} ${x1 - x0} ${y1 - y0}`);
    this.scale = Math.max(x1 - x0, y1 - y0) / 100;
    this.drawBackground();
    zones.forEach((z, k) => {
      const g = el("g", { class: `site-zone ${z.kind}${k === this.selected ? " selected" : ""}`,
        "data-zone": z.name }, this.svg);
      el("polygon", { points: pts(z.polygon || []), "data-index": k }, g);
      if (k === this.selected && this.admin) {
        (z.polygon || []).forEach(([x, y], i) => {
          el("circle", { cx: x, cy: -y, r: this.scale * 1.2, class: "corner", "data-corner": i }, g);
        });
      }
    });
    if (this.drawing) {
      el("polyline", { points: pts(this.drawing), class: "drawing" }, this.svg);
      for (const [x, y] of this.drawing) el("circle", { cx: x, cy: -y, r: this.scale, class: "corner" }, this.svg);
    }
    this.drawCameras();
    this.outputs.draw(this.svg, this.scale);
    // cameras and speakers side by side: their names kept apart
    separateLabels([...this.svg.querySelectorAll("text.label")], this.scale * 0.3);
    this.peopleLayer = el("g", { class: "site-people" }, this.svg);
    this.drawPeople();
    this.renderList();
    this.outputs.renderList();
    this.toForm();
    clearTimeout(this.viewTimer);
    this.viewTimer = setTimeout(() => this.loadViews(), 250);
  }

  // -- the background drawing ----------------------------------------------------------------

  drawBackground() {
    const b = this.background;
    if (!b) return;
    // the similarity taking the drawing's pixels (y down) to the plan's (x, -y)
    const [[u1, v1, x1, y1], [u2, v2, x2, y2]] = b.points;
    const [du, dv, dx, dy] = [u2 - u1, v2 - v1, x2 - x1, -(y2 - y1)];
    const s = Math.hypot(dx, dy) / Math.hypot(du, dv);
    const a = Math.atan2(dy, dx) - Math.atan2(dv, du);
    const [c, n] = [s * Math.cos(a), s * Math.sin(a)];
    const e = x1 - (c * u1 - n * v1);
    const f = -y1 - (n * u1 + c * v1);
    el("image", {
      href: `/api/site/background?v=${this.backgroundVersion}`, width: b.size[0], height: b.size[1],
      transform: `matrix(${c} ${n} ${-n} ${c} ${e} ${f})`, class: "site-background",
      preserveAspectRatio: "none",
    }, this.svg);
  }

  async setBackground() {
    const file = byId("site-bg-file").files[0];
    const numbers = byId("site-bg-points").value.split(/[\s,;]+/).filter(Boolean).map(Number);
    const error = byId("site-error");
    error.textContent = "";
    if (!file || numbers.length !== 8) {
      error.textContent = "choose a PNG or JPEG drawing and give two points: u v x y; u v x y";
      return;
    }
    try {
      const path = `/api/site/background?points=${numbers.join(",")}`;
      this.background = await api.call(path, { method: "PUT", text: file, type: file.type });
      this.backgroundVersion += 1;
      this.render();
    } catch (e) {
      error.textContent = `${e.detail || e.message}`;
    }
  }

  async removeBackground() {
    try {
      await api.call("/api/site/background", { method: "DELETE" });
    } catch (e) {
      if (e.status !== 404) byId("site-error").textContent = `${e.detail || e.message}`;
    }
    this.background = null;
    this.render();
  }

  // -- the cameras and the people on the plan -----------------------------------------------

  async loadCameras() {
    try {
      this.cameras = (await api.cameras()).cameras || [];
    } catch {
      this.cameras = [];
    }
    this.render();
  }

  drawCameras() {
    const g = el("g", { class: "site-cameras" }, this.svg);
    for (const cam of this.cameras || []) {
      if (!Array.isArray(cam.position)) continue;
      const [x, y] = cam.position;
      const node = el("g", { "data-camera": cam.name }, g);
      if (Array.isArray(cam.floor_fov) && cam.floor_fov.length >= 3) {
        el("polygon", { points: pts(cam.floor_fov), class: "fov" }, node);
      }
      el("circle", { cx: x, cy: -y, r: this.scale * 1.4, class: "camera" }, node);
      const label = el("text", { x: x + this.scale * 2, y: -y, class: "label" }, node);
      label.textContent = cam.name;
      label.style.fontSize = `${this.scale * 3}px`;
    }
  }

  async refreshPeople() {
    if (byId("tab-site").hidden) return;
    try {
      this.people = (await api.people()).people || [];
    } catch {
      return;
    }
    this.drawPeople();
  }

  drawPeople() {
    if (!this.peopleLayer) return;
    this.peopleLayer.replaceChildren();
    for (const p of this.people || []) {
      if (!Array.isArray(p.position)) continue;
      const [x, y] = p.position;
      el("circle", { cx: x, cy: -y, r: this.scale * 1.6, "data-person": p.id }, this.peopleLayer);
    }
  }

  // -- the zones in the cameras' pictures ----------------------------------------------------

  async loadViews() {
    if (!this.site) return;
    try {
      this.views = await api.call("/api/site/views", { method: "POST", body: { site: this.site } });
    } catch {
      return; // a draft that does not check yet: the last views stay
    }
    const select = byId("site-camera");
    const names = this.views.cameras.map((c) => c.name);
    if (select.options.length !== names.length) {
      select.replaceChildren(...names.map((n) => { const o = text("option", n); o.value = n; return o; }));
    }
    if (!names.includes(this.camera)) this.camera = names[0] || null;
    select.value = this.camera || "";
    this.drawViews();
  }

  drawViews() {
    const svg = byId("site-camera-svg");
    svg.replaceChildren();
    const cam = this.views && this.views.cameras.find((c) => c.name === this.camera);
    if (!cam) return;
    const view = byId("site-view");
    view.style.aspectRatio = `${cam.size[0]} / ${cam.size[1]}`;
    this.sizeView(cam);
    const img = byId("site-camera-img");
    const src = `/api/cameras/${encodeURIComponent(cam.name)}/snapshot.jpg`;
    if (img.dataset.camera !== cam.name) {
      img.hidden = false;
      img.dataset.camera = cam.name;
      img.src = src;
    }
    const selected = this.zones()[this.selected];
    for (const zone of cam.zones) {
      const g = el("g", { class: `${zone.kind}${selected && selected.name === zone.name ? " selected" : ""}`,
        "data-zone": zone.name }, svg);
      for (const line of zone.lines) {
        el("polyline", { points: line.map(([x, y]) => `${x},${y}`).join(" ") }, g);
      }
    }
    this.survey.draw(svg, cam);
  }

  /** The picture's zoom: "fit" (the column's width), or "1", "2" screen pixels a camera
   * pixel (scrolled within its frame). */
  setZoom(zoom) {
    this.zoom = zoom;
    for (const button of document.querySelectorAll(".site-zoom button")) {
      button.setAttribute("aria-pressed", String(button.dataset.zoom === zoom));
    }
    const cam = this.views && this.views.cameras.find((c) => c.name === this.camera);
    if (cam) this.sizeView(cam);
  }

  sizeView(cam) {
    const view = byId("site-view");
    // CSS pixels of the device's pixels: 1:1 is one camera pixel a screen pixel
    const px = this.zoom === "fit" ? null : (Number(this.zoom) * cam.size[0]) / (window.devicePixelRatio || 1);
    view.style.width = px ? `${px.toFixed(1)}px` : "100%";
  }

  /** The camera pixel under the pointer, as a click there would place it. */
  showPixel(event) {
    const cam = this.views && this.views.cameras.find((c) => c.name === this.camera);
    if (!cam) return;
    const box = byId("site-camera-svg").getBoundingClientRect();
    const u = ((event.clientX - box.left) / box.width) * cam.size[0];
    const v = ((event.clientY - box.top) / box.height) * cam.size[1];
    byId("site-pixel").textContent = `${cam.name} pixel ${u.toFixed(1)}, ${v.toFixed(1)}`;
  }

  async onCameraClick(event) {
    if (!this.camera) return;
    const box = byId("site-camera-svg").getBoundingClientRect();
    const x = (event.clientX - box.left) / box.width;
    const y = (event.clientY - box.top) / box.height;
    if (!this.drawing) { // not drawing a zone: the chosen surveyed point seen here
      const cam = this.views && this.views.cameras.find((c) => c.name === this.camera);
      if (cam) this.survey.click(cam.name, x, y, cam.size);
      return;
    }
    try {
      const at = await api.call("/api/site/floor", { method: "POST", body: { camera: this.camera, x, y, z: 0 } });
      this.drawing.push(this.snapped([at.x, at.y], -1));
      this.render();
    } catch (e) {
      byId("site-error").textContent = `${e.detail || e.message}`;
    }
  }

  renderList() {
    const list = byId("site-zones");
    list.replaceChildren();
    this.zones().forEach((z, k) => {
      const item = text("li", `${z.name} (${z.kind})`, k === this.selected ? "selected" : "");
      item.dataset.zone = z.name;
      item.addEventListener("click", () => { this.selected = k; this.render(); });
      list.appendChild(item);
    });
    byId("site-save").disabled = !this.dirty;
    byId("site-finish").hidden = !this.drawing;
  }

  toForm() {
    const z = this.zones()[this.selected];
    byId("site-form").hidden = !z;
    if (!z) return;
    const form = byId("site-form");
    for (const input of form.querySelectorAll("input, select")) input.disabled = !this.admin;
    for (const note of form.querySelectorAll(".field-error")) note.textContent = "";
    for (const node of form.querySelectorAll(".invalid")) node.classList.remove("invalid");
    byId("site-name").value = z.name;
    byId("site-kind").value = z.kind;
    byId("site-z0").value = z.z ? z.z[0] : 0;
    byId("site-z1").value = z.z ? z.z[1] : 2.5;
    byId("site-margin").value = z.margin_m ?? "";
    byId("site-voltage").value = z.voltage_kv ?? "";
    byId("site-distance").value = z.distance_table ?? "";
    byId("site-joints").value = (z.joints || []).join(", ");
    byId("site-power").value = z.power ? JSON.stringify(z.power, null, 1) : "";
    for (const node of form.querySelectorAll("textarea")) node.disabled = !this.admin;
    byId("site-points").value = (z.polygon || []).map(([x, y]) => `${x} ${y}`).join("; ");
  }

  fromForm() {
    const z = this.zones()[this.selected];
    if (!z || !this.admin) return;
    z.name = byId("site-name").value;
    z.kind = byId("site-kind").value;
    z.z = [Number(byId("site-z0").value), Number(byId("site-z1").value)];
    for (const [key, id] of [["margin_m", "site-margin"], ["voltage_kv", "site-voltage"]]) {
      const v = byId(id).value.trim();
      if (v === "") delete z[key];
      else z[key] = Number(v);
    }
    const table = byId("site-distance").value.trim();
    if (table) z.distance_table = table;
    else delete z.distance_table;
    const joints = byId("site-joints").value.split(/[\s,]+/).filter(Boolean);
    if (joints.length) z.joints = joints;
    else delete z.joints;
    const power = byId("site-power").value.trim();
    try {
      if (power) z.power = JSON.parse(power);
      else delete z.power;
      fieldError("site-power", "");
    } catch {
      fieldError("site-power", "not JSON: a table as the site file's [zones.power]");
    }
    const corners = byId("site-points").value.split(";").map((p) => p.trim().split(/[\s,]+/).map(Number));
    if (corners.length >= 3 && corners.every((c) => c.length === 2 && c.every(Number.isFinite))) {
      z.polygon = corners;
    }
    this.changed(false);
  }

  changed(rerender = true) {
    this.dirty = true;
    byId("site-info").textContent = `version ${this.version}, changed: not saved`;
    if (rerender) this.render();
    else { this.renderList(); this.redrawPolygons(); }
  }

  redrawPolygons() {
    for (const polygon of this.svg.querySelectorAll("polygon[data-index]")) {
      const z = this.zones()[Number(polygon.dataset.index)];
      if (z) polygon.setAttribute("points", pts(z.polygon || []));
    }
  }

  // -- the plan's pointer ---------------------------------------------------------------------

  metres(event) {
    const point = this.svg.createSVGPoint();
    point.x = event.clientX;
    point.y = event.clientY;
    const m = point.matrixTransform(this.svg.getScreenCTM().inverse());
    return [m.x, -m.y];
  }

  snapped([x, y], skip) {
    let best = null;
    this.zones().forEach((z, k) => {
      if (k === skip) return;
      for (const [cx, cy] of z.polygon || []) {
        const d = Math.hypot(cx - x, cy - y);
        if (d <= SNAP_M && (!best || d < best[0])) best = [d, [cx, cy]];
      }
    });
    return best ? [...best[1]] : [round(x), round(y)];
  }

  onDown(event) {
    if (!this.admin || !this.site) return;
    const at = this.metres(event);
    if (this.outputs.place(at)) return;
    if (this.drawing) {
      this.drawing.push(this.snapped(at, -1));
      this.render();
      return;
    }
    const corner = event.target.dataset ? event.target.dataset.corner : undefined;
    if (corner !== undefined) {
      this.drag = Number(corner);
      this.svg.setPointerCapture(event.pointerId);
      return;
    }
    const index = event.target.dataset ? event.target.dataset.index : undefined;
    if (index !== undefined) {
      this.selected = Number(index);
      this.render();
    }
  }

  onMove(event) {
    if (this.drag === null || this.drag === undefined) return;
    const z = this.zones()[this.selected];
    if (!z) return;
    z.polygon[this.drag] = this.snapped(this.metres(event), this.selected);
    this.changed();
  }

  startDrawing() {
    if (!this.admin || !this.site) return;
    this.drawing = [];
    byId("site-error").textContent = "Click the new zone's corners on the plan, then Finish.";
    this.render();
  }

  finishDrawing() {
    const corners = this.drawing || [];
    this.drawing = null;
    if (corners.length >= 3) {
      const names = new Set(this.zones().map((z) => z.name));
      let n = this.zones().length + 1;
      while (names.has(`zone_${n}`)) n += 1;
      this.site.zones = [...this.zones(), { name: `zone_${n}`, kind: "restricted", polygon: corners, z: [0, 2.5] }];
      this.selected = this.site.zones.length - 1;
      byId("site-error").textContent = "";
      this.changed();
    } else {
      byId("site-error").textContent = "A zone needs at least 3 corners.";
      this.render();
    }
  }

  deleteZone() {
    if (!this.admin || this.selected < 0) return;
    this.site.zones = this.zones().filter((_, k) => k !== this.selected);
    this.selected = -1;
    this.changed();
  }

  // -- saving and the history -----------------------------------------------------------------

  async save(site = this.site) {
    const error = byId("site-error");
    error.textContent = "";
    try {
      const answer = await api.call("/api/site", { method: "PUT", body: { version: this.version, site } });
      this.dirty = false;
      byId("site-info").textContent = `version ${answer.version}: saved, taken at the next step`;
      await this.load();
    } catch (e) {
      error.textContent = e.status === 409
        ? `${e.detail} (Reload to see it; your changes are kept until then.)`
        : `${e.detail || e.message}`;
      if (e.status === 400) this.showAtField(`${e.detail || ""}`);
    }
  }

  // The API's error (`zone 'name': key: ...`) shown at the field it names, its zone chosen.
  showAtField(detail) {
    const m = /^zone '(.+?)': ([a-z_]+)/.exec(detail);
    if (!m) return;
    const k = this.zones().findIndex((z) => z.name === m[1]);
    if (k < 0) return;
    this.selected = k;
    this.render();
    const word = m[2] === "unknown" && /joint/.test(detail) ? "joints" : m[2];
    const id = FIELDS[word] || (/joint/.test(word) ? "site-joints" : null);
    if (id) {
      fieldError(id, detail.slice(m[0].indexOf(":") + 2));
      byId(id).focus();
    }
  }

  async loadHistory() {
    const list = byId("site-history");
    list.replaceChildren();
    let versions = [];
    try {
      versions = (await api.call("/api/site/history")).versions || [];
    } catch {
      return;
    }
    for (const v of versions) {
      const item = text("li", `${v.version} by ${v.by}, ${new Date(v.at * 1000).toLocaleString()}`);
      item.dataset.version = v.version;
      if (this.admin && v.version !== this.version) {
        const button = text("button", "Restore", "site-restore");
        button.type = "button";
        button.addEventListener("click", () => this.restore(v.version));
        item.appendChild(button);
      }
      list.appendChild(item);
    }
  }

  async restore(version) {
    try {
      const old = await api.call(`/api/site/history/${encodeURIComponent(version)}`);
      await this.save(old.site);
    } catch (e) {
      byId("site-error").textContent = `${e.detail || e.message}`;
    }
  }
}
