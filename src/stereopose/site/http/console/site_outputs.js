// The Site tab's warnings on site: each speaker and signal of the site file on the plan where
// it hangs (its `position`), a line to each zone it covers, and for an admin its editor: the
// zones it covers (ticked), its place (typed, or clicked on the plan after "Place"). Its
// address, codec and coils are the site file's (shown, not edited here). The changes are the
// site's: saved with it (PUT /api/site), checked by the service (a bad zone named in the
// answer). Every name goes in as text, never as markup.

import { byId, text } from "./dom.js";
import { el } from "./svg.js";


function centre(polygon) {
  const n = polygon.length || 1;
  return [polygon.reduce((s, p) => s + p[0], 0) / n, polygon.reduce((s, p) => s + p[1], 0) / n];
}

export class SiteOutputs {
  /** editor: the Site tab (its site, its plan's scale, `changed()` after an edit). */
  constructor(editor) {
    this.editor = editor;
    this.selected = null; // ["speakers" | "signals", index]
    this.placing = false; // the next click on the plan places the selected output
    byId("site-output-place").addEventListener("click", () => this.startPlacing());
    byId("site-output-form").addEventListener("input", () => this.fromForm());
  }

  outputs() {
    const site = this.editor.site || {};
    const list = (key) => (Array.isArray(site[key]) ? site[key] : []).map((o, i) => [key, i, o]);
    return [...list("speakers"), ...list("signals")];
  }

  /** The places of the outputs (the plan's bounds take them in). */
  positions() {
    return this.outputs().map(([, , o]) => o.position).filter(Array.isArray);
  }

  current() {
    if (!this.selected) return null;
    const [key, i] = this.selected;
    const list = (this.editor.site || {})[key];
    return Array.isArray(list) ? list[i] || null : null;
  }

  // -- on the plan --------------------------------------------------------------------------

  draw(svg, scale) {
    this.svg = svg;
    this.scale = scale;
    const zones = new Map(this.editor.zones().map((z) => [z.name, z]));
    const g = el("g", { class: "site-outputs" }, svg);
    for (const [key, i, o] of this.outputs()) {
      if (!Array.isArray(o.position)) continue;
      const [x, y] = o.position;
      const chosen = this.selected && this.selected[0] === key && this.selected[1] === i;
      const node = el("g", { class: `site-output ${key}${chosen ? " selected" : ""}`,
        "data-output": o.name }, g);
      for (const name of o.zones || []) {
        const z = zones.get(name);
        if (!z || !Array.isArray(z.polygon)) continue;
        const [cx, cy] = centre(z.polygon);
        el("line", { x1: x, y1: -y, x2: cx, y2: -cy, class: "covers" }, node);
      }
      const r = scale * 1.8;
      if (key === "speakers") el("circle", { cx: x, cy: -y, r, class: "mark" }, node);
      else el("rect", { x: x - r, y: -y - r, width: 2 * r, height: 2 * r, class: "mark" }, node);
      const label = el("text", { x: x + scale * 2.5, y: -y - scale, class: "label" }, node);
      label.textContent = o.name;
      label.style.fontSize = `${scale * 3}px`;
    }
  }

  /** A click on the plan while placing: the selected output put there; whether it was. */
  place(at) {
    const o = this.current();
    if (!this.placing || !o) return false;
    this.placing = false;
    o.position = [Number(at[0].toFixed(2)), Number(at[1].toFixed(2))];
    byId("site-error").textContent = "";
    this.editor.changed();
    return true;
  }

  startPlacing() {
    if (!this.editor.admin || !this.current()) return;
    this.placing = true;
    byId("site-error").textContent = `Click where ${this.current().name} hangs on the plan.`;
  }

  // -- the list and the form ------------------------------------------------------------------

  renderList() {
    const list = byId("site-outputs");
    const rows = this.outputs().map(([key, i, o]) => {
      const li = text("li", "");
      li.dataset.output = o.name;
      li.append(text("span", o.name), text("span", ` ${key === "speakers" ? "speaker" : "signal"}`, "muted"));
      if (!Array.isArray(o.position)) li.append(text("span", " (not placed)", "muted"));
      if (this.selected && this.selected[0] === key && this.selected[1] === i) li.className = "selected";
      li.addEventListener("click", () => { this.selected = [key, i]; this.editor.render(); });
      return li;
    });
    list.replaceChildren(...rows);
    byId("site-outputs-none").hidden = rows.length > 0;
    this.toForm();
  }

  toForm() {
    const o = this.current();
    const form = byId("site-output-form");
    form.hidden = !o;
    if (!o) return;
    const [key] = this.selected;
    byId("site-output-what").textContent = key === "speakers"
      ? `${o.url || ""}${o.codec ? ` (${o.codec})` : ""}`
      : `${o.host || ""}:${o.port || 502} unit ${o.unit ?? 1}, coils ${JSON.stringify(o.coils || {})}`;
    const boxes = this.editor.zones().map((z) => {
      const label = text("label", "", "site-output-zone");
      const box = document.createElement("input");
      box.type = "checkbox";
      box.value = z.name;
      box.checked = (o.zones || []).includes(z.name);
      box.disabled = !this.editor.admin;
      label.append(box, text("span", ` ${z.name}`));
      return label;
    });
    byId("site-output-zones").replaceChildren(...boxes);
    const position = byId("site-output-position");
    position.value = Array.isArray(o.position) ? `${o.position[0]} ${o.position[1]}` : "";
    position.disabled = !this.editor.admin;
  }

  fromForm() {
    const o = this.current();
    if (!o || !this.editor.admin) return;
    o.zones = [...byId("site-output-zones").querySelectorAll("input:checked")].map((b) => b.value);
    const xy = byId("site-output-position").value.trim().split(/[\s,]+/).filter(Boolean).map(Number);
    if (xy.length === 0) delete o.position;
    else if (xy.length === 2 && xy.every(Number.isFinite)) o.position = xy;
    this.editor.changed(false);
    this.redraw(); // the plan's marks only: the form is left as it is being typed
  }

  redraw() {
    if (!this.svg) return;
    const old = this.svg.querySelector("g.site-outputs");
    if (old) old.remove();
    this.draw(this.svg, this.scale);
    const people = this.svg.querySelector("g.site-people");
    if (people) this.svg.appendChild(people); // the people stay on top
  }
}
