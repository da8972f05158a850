// The Live tab's "On site" panel: each speaker and signal of the site's warnings, what it
// sounds now and why (the zone, the hazard, the person, the distance and side; a call for
// help; a test), its health, and its silence while one lasts. An admin tests an output, or
// silences it for a time with a reason, or lets it sound again (api /api/warnings). Every
// text from the server goes in as text, never as markup.

import * as api from "./api.js";
import { text } from "./dom.js";

const SILENCE_CHOICES = [[15, "15 min"], [60, "1 h"], [240, "4 h"], [480, "8 h"]];
const CALL_TEXT = {
  person_down: "call for help: person down",
  step_wrong_position: "wrong position for a ticket's step",
  test: "test",
};
const HEALTH_TEXT = {
  up: "up",
  down: "DOWN",
  unknown: "not answered yet",
  "not verifiable": "not verifiable",
};


function clock(unixS) {
  return new Date(unixS * 1000).toLocaleTimeString([], { hour: "2-digit", minute: "2-digit" });
}

/** What an output sounds: one line per hazard or call. */
export function soundingText(item) {
  if (item.zone !== undefined) {
    const what = item.kind === "enter" ? "inside" : "near";
    const where = item.side && item.side !== "nearby" ? `, ${item.side}` : "";
    return `P${item.priority} person ${item.person} ${what} ${item.zone}, ${item.distance_m} m${where}`;
  }
  const what = CALL_TEXT[item.kind] || String(item.kind).replaceAll("_", " ");
  return item.kind === "test" ? what : `P${item.priority} ${what}, person ${item.person}`;
}

export class OnSitePanel {
  constructor(root) {
    this.root = root;
    this.list = root.querySelector("#onsite-outputs");
    this.info = root.querySelector("#onsite-info");
    this.said = root.querySelector("#onsite-said"); // the answer to an admin's last act
    this.role = "viewer";
    this.pending = null;
    this.busy = false; // an admin's form being filled: not redrawn under the hands
  }

  setRole(role) {
    this.role = role;
  }

  /** Asks for the outputs' state and draws it; the panel is hidden where the site has none. */
  async refresh() {
    if (this.pending || this.busy) return;
    this.pending = api.warnings();
    try {
      this.draw(await this.pending);
    } catch (error) {
      this.info.textContent = `not loaded: ${error.detail || error.message}`;
    } finally {
      this.pending = null;
    }
  }

  draw(body) {
    const outputs = body.outputs || [];
    this.root.hidden = outputs.length === 0; // a site without speakers or signals
    const sounding = outputs.filter((o) => (o.sounding || []).length).length;
    this.info.textContent = sounding ? `${sounding} sounding now` : "quiet";
    this.list.replaceChildren(...outputs.map((o) => this.row(o)));
  }

  row(output) {
    const li = text("li", "", "onsite-output");
    li.dataset.output = output.name;
    li.dataset.health = output.health;
    const head = text("div", "", "onsite-head");
    head.append(text("strong", output.name), text("span", ` ${output.type}`, "muted"));
    const health = HEALTH_TEXT[output.health] || output.health;
    head.append(text("span", health, `onsite-health health-${output.health.replace(" ", "-")}`));
    li.append(head);
    li.append(text("div", `covers ${(output.zones || []).join(", ")}`, "muted onsite-zones"));
    for (const item of output.sounding || []) {
      li.append(text("div", soundingText(item), "onsite-sounding"));
    }
    if (output.silenced) {
      li.dataset.silenced = "true";
      const s = output.silenced;
      const said = `silenced until ${clock(s.until)} by ${s.by}: ${s.reason}`;
      li.append(text("div", said, "onsite-silenced"));
    }
    if (this.role === "admin") li.append(this.actions(output));
    return li;
  }

  actions(output) {
    const box = text("div", "", "onsite-actions");
    const name = output.name;
    if (output.silenced) {
      const again = text("button", "Sound again", "onsite-unsilence");
      again.type = "button";
      again.addEventListener("click", () => this.act(() => api.unsilenceOutput(name),
        `${name} sounds again`));
      box.append(again);
      return box;
    }
    const test = text("button", "Test", "onsite-test");
    test.type = "button";
    test.title = output.type === "speaker" ? "say 'this is a test' on it" : "pulse its coils";
    test.addEventListener("click", () => this.act(() => api.testOutput(name), `${name} tested`));
    const form = text("form", "", "onsite-silence");
    const minutes = text("select", "", "onsite-minutes");
    for (const [value, label] of SILENCE_CHOICES) {
      const option = text("option", label);
      option.value = String(value);
      minutes.append(option);
    }
    const reason = text("input", "", "onsite-reason");
    reason.placeholder = "reason";
    reason.required = true;
    reason.maxLength = 500;
    reason.addEventListener("focus", () => { this.busy = true; });
    reason.addEventListener("blur", () => { this.busy = false; });
    const silence = text("button", "Silence");
    silence.type = "submit";
    form.append(minutes, reason, silence);
    form.addEventListener("submit", (e) => {
      e.preventDefault();
      this.busy = false;
      this.act(() => api.silenceOutput(name, Number(minutes.value), reason.value),
        `${name} silenced`);
    });
    box.append(test, form);
    return box;
  }

  async act(call, done) {
    this.said.textContent = "…";
    try {
      await call();
      this.said.textContent = done;
      await this.refresh();
    } catch (error) {
      this.said.textContent = error.detail || error.message;
    }
  }
}
