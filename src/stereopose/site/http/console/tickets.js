// Tickets: the site's work and operation tickets (/api/tickets). The list with each one's
// state and progress; the chosen one's steps ticking as they are done (who, when, how long,
// in order or not), its deviations, its roles (bound by clicking a person seen now), start,
// end and abort for operators and admins, its report, and the 3D replay of the whole job or
// of any step. A new ticket is posted as its TOML file (docs/formats.md#tickets).

import * as api from "./api.js";
import { byId, text } from "./dom.js";
import { dateTime, typeText } from "./feed.js";

const PERIOD_MS = 1000;
const BEFORE_S = 3; // a step's replay starts this long before its action
const AFTER_S = 2; // ... and ends this long after it
const STATE_TEXT = { done: "done", open: "open", timed_out: "timed out" };
const CLIPS_MS = 5000; // the ticket's events (their clips) asked again at most this often
// Events close together share one clip per camera, named after the first: a step's action
// that fell inside another alarm's clip is shown by that clip (begun at most this long before)
const SHARED_CLIP_S = 10;

const seconds = (s) => (typeof s === "number" ? `${s.toFixed(1)} s` : "-");
const who = (id) => (id === null || id === undefined ? "unbound" : `id ${id}`);

/** A new ticket's template: the site's first zones as its step's position and target. */
function template(zones) {
  const names = zones.map((z) => z.name);
  const position = names.find((n) => !/handle|panel|busbar/.test(n)) || names[0] || "ZONE";
  const target = names.find((n) => n !== position) || position;
  return [
    'id = "OT-0001"', 'title = "Switching"', 'kind = "operation"   # or "work"',
    "isolated = []         # work: the energized zones made dead for the job",
    "supervise_m = 3.0", "absent_s = 10.0", "", "[roles]", 'operator = "auto"',
    'supervisor = "auto"', "", "[[steps]]", 'name = "first step"', `position = "${position}"`,
    `target = "${target}"`, "hold_s = 1.0", "max_s = 300.0", "",
  ].join("\n");
}

export class Tickets {
  constructor(replay) {
    this.replay = replay;
    this.role = "viewer";
    this.zones = [];
    this.people = [];
    this.selected = null;
    this.current = null;
    this.timer = null;
    this.asked = 0;
    this.clips = { ticket: null, at: 0, steps: new Map(), deviations: new Map() };
    this.rows = byId("t-rows");
    this.info = byId("t-info");
    this.newText = byId("t-new-text");
    this.newError = byId("t-new-error");
    byId("t-new-form").addEventListener("submit", (e) => {
      e.preventDefault();
      this.create();
    });
    byId("t-start").addEventListener("click", () => this.act("start"));
    byId("t-end").addEventListener("click", () => this.act("end", { aborted: false }));
    byId("t-abort").addEventListener("click", () => this.act("end", { aborted: true }));
    byId("t-replay-job").addEventListener("click", () => this.replayJob());
  }

  setRole(role) {
    this.role = role;
    const acts = role === "operator" || role === "admin";
    for (const el of document.querySelectorAll(".t-operator")) el.hidden = !acts;
  }

  setZones(zones) {
    this.zones = zones;
    if (!this.newText.value) this.newText.value = template(zones);
  }

  setPeople(people) {
    const ids = (people || []).map((p) => p.id).sort((a, b) => a - b);
    if (ids.join(",") === this.people.join(",")) return;
    this.people = ids;
    this.renderPeople();
  }

  show(active) {
    clearInterval(this.timer);
    this.timer = null;
    if (!active) return;
    this.refresh();
    this.timer = setInterval(() => this.refresh(), PERIOD_MS);
  }

  async refresh() {
    const asked = ++this.asked;
    try {
      const list = await api.tickets();
      const detail = this.selected ? await api.ticket(this.selected).catch((error) => {
        if (error instanceof api.ApiError && error.status === 404) return null;
        throw error;
      }) : null;
      if (asked !== this.asked) return;
      this.renderList(list.tickets || []);
      if (this.selected && !detail) this.selected = null;
      if (!this.selected && (list.tickets || []).length) {
        // the first active ticket, else the newest
        const all = list.tickets;
        this.selected = (all.find((t) => t.state === "active") || all[all.length - 1]).id;
        return this.refresh();
      }
      this.renderDetail(detail ? detail.ticket : null);
      this.info.textContent = "";
      if (detail) this.fetchClips(detail.ticket);
    } catch (error) {
      if (asked !== this.asked || (error instanceof api.ApiError && error.status === 401)) return;
      this.info.textContent = `not loaded: ${error.detail || error.message}`;
    }
  }

  select(id) {
    this.selected = id;
    this.refresh();
  }

  renderList(tickets) {
    this.rows.replaceChildren();
    for (const t of tickets) {
      const tr = document.createElement("tr");
      tr.dataset.ticket = t.id;
      tr.dataset.state = t.state;
      tr.classList.toggle("selected", t.id === this.selected);
      tr.tabIndex = 0;
      for (const [value, cls] of [[t.id, "id"], [t.title, ""], [t.state + (t.starting ? " (starting)" : t.ending ? " (ending)" : ""), `t-state t-state-${t.state}`],
        [`${t.steps_done}/${t.steps_total}`, "num"], [String(t.deviations), t.deviations ? "num dev" : "num"]]) {
        const td = text("td", value, cls);
        tr.appendChild(td);
      }
      tr.addEventListener("click", () => this.select(t.id));
      tr.addEventListener("keydown", (e) => { if (e.key === "Enter") this.select(t.id); });
      this.rows.appendChild(tr);
    }
    byId("t-empty").hidden = tickets.length > 0;
  }

  renderDetail(t) {
    this.current = t;
    byId("t-detail").hidden = !t;
    if (!t) return;
    byId("t-title").textContent = `${t.id} · ${t.title || t.kind}`;
    const state = byId("t-state");
    state.textContent = t.state + (t.starting ? " (starting)" : t.ending ? " (ending)" : "");
    state.dataset.state = t.state;
    state.className = `t-state t-state-${t.state}`;
    const live = t.state === "active" || t.state === "planned";
    byId("t-start").hidden = !(t.state === "planned" && !t.starting) || !this.acts();
    byId("t-end").hidden = !(t.state === "active" && !t.ending) || !this.acts();
    byId("t-abort").hidden = !live || t.ending || !this.acts();
    byId("t-replay-job").disabled = typeof t.started_wall !== "number";
    byId("t-report").href = api.ticketReportUrl(t.id);
    const times = [`kind ${t.kind}`];
    if (t.started_wall) times.push(`started ${dateTime(t.started_wall)}${t.started_by ? ` by ${t.started_by}` : ""}`);
    if (t.ended_wall) times.push(`ended ${dateTime(t.ended_wall)}${t.ended_by ? ` by ${t.ended_by}` : ""}`);
    if ((t.isolated || []).length) times.push(`isolated: ${t.isolated.join(", ")}`);
    if (typeof t.slot === "number") times.push(`SCADA slot ${t.slot}`);
    byId("t-times").textContent = times.join(" · ");
    byId("t-operator").textContent = who(t.operator);
    const required = !t.ticket || !t.ticket.roles || "supervisor" in t.ticket.roles;
    byId("t-supervisor").textContent = required ? who(t.supervisor) : "none required";
    byId("t-bind").hidden = !live || !this.acts();
    this.renderSteps(t);
    this.renderDeviations(t);
    const result = byId("t-result");
    result.hidden = !t.result;
    if (t.result) {
      const r = t.result;
      result.textContent = `${r.done.length} of ${r.steps} steps done, ${r.done_in_order.length} in order; `
        + `missed: ${r.missed.length ? r.missed.join(", ") : "none"}; deviations: ${r.deviations}`
        + (r.aborted ? " (aborted)" : "");
    }
  }

  acts() { return this.role === "operator" || this.role === "admin"; }

  renderSteps(t) {
    const list = byId("t-steps");
    list.replaceChildren();
    (t.steps || []).forEach((s, i) => {
      const li = document.createElement("li");
      li.dataset.step = s.name;
      li.dataset.index = String(i);
      li.dataset.state = s.state;
      li.className = `t-step t-step-${s.state}${s.in_order === false ? " t-out-of-order" : ""}${s.failed ? " t-failed" : ""}`;
      li.appendChild(text("span", s.state === "done" ? "✔" : s.state === "timed_out" ? "⌛" : "○", "t-mark"));
      const body = document.createElement("div");
      body.className = "t-step-body";
      body.appendChild(text("strong", `${i + 1}. ${s.name}${s.optional ? " (optional)" : ""}`));
      body.appendChild(text("div", `at ${s.position}, hand in ${s.target}`, "muted"));
      const facts = [STATE_TEXT[s.state] || s.state];
      if (s.done_wall) facts.push(`${dateTime(s.done_wall)} by id ${s.by}`);
      if (typeof s.done_t === "number" && typeof s.onset_t === "number") facts.push(`held ${seconds(s.done_t - s.onset_t)}`);
      if (s.where) facts.push(`stood at (${s.where.map((v) => v.toFixed(2)).join(", ")}) m`);
      if (s.in_order === false) facts.push("out of order");
      if (s.failed) facts.push(`wrong: ${s.failed}`);
      body.appendChild(text("div", facts.join(" · "), "t-facts"));
      const clips = this.clips.ticket === t.id ? this.clips.steps.get(s.name) : null;
      if (clips) body.appendChild(this.clipLinks(clips));
      li.appendChild(body);
      const replay = text("button", "Replay", "t-replay-step");
      replay.type = "button";
      replay.disabled = !this.stepWindow(t, i);
      replay.addEventListener("click", () => this.replayStep(i));
      li.appendChild(replay);
      list.appendChild(li);
    });
  }

  renderDeviations(t) {
    const list = byId("t-deviations");
    list.replaceChildren();
    for (const d of [...(t.deviation_list || [])].reverse()) {
      const li = text("li", `${dateTime(d.wall_t)} ${typeText(d.type)}${d.step ? `: ${d.step}` : ""} `);
      li.dataset.type = d.type;
      const clips = this.clips.ticket === t.id ? this.clips.deviations.get(`${d.type}|${d.step || ""}`) : null;
      if (clips) li.appendChild(this.clipLinks(clips));
      list.appendChild(li);
    }
    byId("t-no-deviations").hidden = (t.deviation_list || []).length > 0;
  }

  /** The clips of the ticket's events (each step done, each deviation), from the event log;
   * at most every CLIPS_MS, and whenever another ticket is chosen. */
  async fetchClips(t) {
    const now = Date.now();
    if (this.clips.ticket === t.id && now - this.clips.at < CLIPS_MS) return;
    this.clips.ticket = t.id;
    this.clips.at = now;
    let answer;
    let around;
    const since = typeof t.started_wall === "number" ? t.started_wall - SHARED_CLIP_S : null;
    const until = typeof t.ended_wall === "number" ? t.ended_wall : now / 1000;
    try {
      [answer, around] = await Promise.all([
        api.events({ ticket: t.id, limit: 1000 }),
        since === null ? { events: [] } : api.events({ since: since.toFixed(3), until: until.toFixed(3), limit: 1000 }),
      ]);
    } catch {
      return; // tried again later
    }
    // the clips begun in the job, oldest first: [wall_t, clips]
    const shared = (around.events || []).filter((e) => (e.clips || []).length)
      .map((e) => [e.wall_t, e.clips]).sort((a, b) => a[0] - b[0]);
    const covering = (wall) => {
      let found = null;
      for (const [at, clips] of shared) if (at <= wall + 1 && at >= wall - SHARED_CLIP_S) found = clips;
      return found;
    };
    const steps = new Map();
    const deviations = new Map();
    for (const e of answer.events || []) {
      const clips = (e.clips || []).length ? e.clips : covering(e.wall_t);
      if (!clips) continue;
      const key = `${e.type}|${e.step || ""}`;
      if (e.type === "step_done" && e.step) steps.set(e.step, clips);
      else if (e.type !== "ticket_started" && e.type !== "ticket_completed") {
        deviations.set(key, [...new Set([...(deviations.get(key) || []), ...clips])]);
      }
    }
    this.clips = { ticket: t.id, at: now, steps, deviations };
    if (this.current && this.current.id === t.id) {
      this.renderSteps(this.current);
      this.renderDeviations(this.current);
    }
  }

  clipLinks(urls) {
    const box = document.createElement("span");
    box.className = "t-clips";
    for (const url of urls || []) {
      const name = String(url).split("/").pop();
      const a = text("a", name.replace(/^.*_/, "").replace(/\.mp4$/, ""), "button t-clip");
      a.href = `/api/clips/${encodeURIComponent(decodeURIComponent(name))}`;
      a.download = "";
      a.title = `download ${name}`;
      box.appendChild(a);
    }
    return box;
  }

  renderPeople() {
    const box = byId("t-people");
    box.replaceChildren();
    for (const id of this.people) {
      const b = text("button", `id ${id}`);
      b.type = "button";
      b.dataset.person = String(id);
      b.title = "bind the chosen role to this person";
      b.addEventListener("click", () => this.bind(id));
      box.appendChild(b);
    }
    if (!this.people.length) box.appendChild(text("span", "nobody seen now", "muted"));
  }

  /** [since, until] of step i's replay: its action with a margin, or (not done) from the
   * previous step's end (or the start) to now. */
  stepWindow(t, i) {
    const s = (t.steps || [])[i];
    if (!s || typeof t.started_wall !== "number") return null;
    if (typeof s.onset_wall === "number" && typeof s.done_wall === "number") {
      return [s.onset_wall - BEFORE_S, s.done_wall + AFTER_S];
    }
    const before = (t.steps || []).slice(0, i).map((x) => x.done_wall).filter((x) => typeof x === "number");
    const since = before.length ? Math.max(...before) : t.started_wall;
    const until = typeof t.ended_wall === "number" ? t.ended_wall : Date.now() / 1000;
    return until > since ? [since, until] : null;
  }

  replayStep(i) {
    const t = this.current;
    const window = t && this.stepWindow(t, i);
    if (!window) return;
    const s = t.steps[i];
    this.replay.open({
      since: window[0], until: window[1], title: `${t.id}, step ${i + 1}: ${s.name}`,
      highlight: [s.position, s.target],
    });
  }

  replayJob() {
    const t = this.current;
    if (!t || typeof t.started_wall !== "number") return;
    const until = typeof t.ended_wall === "number" ? t.ended_wall : Date.now() / 1000;
    const zones = (t.steps || []).flatMap((s) => [s.position, s.target]);
    this.replay.open({ since: t.started_wall - 1, until: until + 1, title: `${t.id}: the whole job`, highlight: zones });
  }

  async act(act, body) {
    const t = this.current;
    if (!t) return;
    try {
      await api.ticketAct(t.id, act, body);
      this.info.textContent = "";
    } catch (error) {
      this.info.textContent = `${act} refused: ${error.detail || error.message}`;
    }
    this.refresh();
  }

  bind(person) {
    this.act("bind", { role: byId("t-bind-role").value, person });
  }

  async create() {
    this.newError.textContent = "";
    try {
      const answer = await api.addTicket(this.newText.value);
      this.selected = answer.ticket.id;
      this.newText.value = "";
      this.setZones(this.zones);
    } catch (error) {
      this.newError.textContent = error.detail || error.message;
    }
    this.refresh();
  }
}
