// The alarm feed, newest first: one line per incident (a hazard's alarm: its occurrences
// counted on the line, its priority's colour, its state, first-out marked) and one per event
// that belongs to no incident. What makes a new incident unmistakable until someone
// acknowledges it: the flashing banner (unacknowledged incidents only), the counter and the
// sound (which can be muted). Ack and Shelve act on the incident.

import { ackIncident, ApiError, shelveIncident } from "./api.js";
import { Alarm } from "./sound.js";

const MAX_ITEMS = 300; // the feed keeps the newest; history has the rest

const TYPE_TEXT = {
  enter: "entered",
  exit: "left",
  approach: "approaching",
  dwell: "dwelling in",
  left_work_area: "left work area",
  camera_down: "camera down",
  camera_up: "camera up",
  camera_moved: "camera moved",
  calibration_drift: "calibration drift",
  person_down: "person down",
  lone_worker: "alone",
  work_position: "out of work position",
  service_stalled: "service stalled",
  warning_output_down: "warning output down",
  warning_output_back: "warning output back",
  warning_output_silenced: "warning output silenced",
  warning_output_unsilenced: "warning output sounding again",
  warning_output_test: "warning output tested",
};

export const PRIORITY_NAMES = { 1: "critical", 2: "high", 3: "medium", 4: "low" };
const STATE_TEXT = {
  active: "active",
  acknowledged: "acknowledged",
  cleared: "cleared, not acknowledged",
  closed: "closed",
};
const UNACKED = new Set(["active", "cleared"]);
export const SHELVE_CHOICES = [[900, "15 min"], [3600, "1 h"], [4 * 3600, "4 h"], [8 * 3600, "8 h"]];

export const typeText = (type) => TYPE_TEXT[type] || String(type).replaceAll("_", " ");

export function clock(wallT) {
  if (typeof wallT !== "number") return "-";
  return new Date(wallT * 1000).toLocaleTimeString([], { hour12: false });
}

export function dateTime(wallT) {
  if (typeof wallT !== "number") return "-";
  const d = new Date(wallT * 1000);
  return `${d.toLocaleDateString()} ${d.toLocaleTimeString([], { hour12: false })}`;
}

const known = (v) => v !== null && v !== undefined;

/** "person 3 entered overhead_busbar (energized)", the words of one event. */
export function describe(e) {
  const parts = [];
  if (known(e.person) && e.person >= 0) parts.push(`person ${e.person}`);
  parts.push(typeText(e.type));
  if (e.zone) parts.push(e.zone);
  if (e.kind && e.zone && e.kind !== e.zone) parts.push(`(${e.kind})`);
  if (e.rule) parts.push(`(rule ${e.rule})`);
  if (e.ticket) parts.push(`(ticket ${e.ticket}${e.step ? `, step ${e.step}` : ""})`);
  if (e.failed && e.ticket) parts.push(`· wrong: ${e.failed}`);
  if (e.camera && !String(e.type).startsWith("camera")) parts.push(`· ${e.camera}`);
  else if (e.camera && !e.zone) parts.push(e.camera);
  return parts.join(" ");
}

/** The words of an incident: its hazard and its worst occurrence (an approach that became an
 * entry reads "entered"; a record of an earlier version: the type that raised it), and the
 * latest one when that differs. */
export function describeIncident(rec, zoneKinds = new Map()) {
  const parts = [];
  const worst = rec.worst_type || rec.type;
  if (known(rec.person) && rec.person >= 0) parts.push(`person ${rec.person}`);
  parts.push(typeText(worst));
  if (rec.zone) {
    parts.push(rec.zone);
    const kind = zoneKinds.get(rec.zone);
    if (kind && kind !== rec.zone) parts.push(`(${kind})`);
  }
  if (rec.rule) parts.push(`(rule ${rec.rule})`);
  if (rec.camera && !rec.zone) parts.push(rec.camera);
  if (rec.key && rec.key[0] === "service") parts.push("(the service)");
  if (rec.key && rec.key[0] === "ticket") parts.push(`(ticket ${rec.key[1]}, ${rec.key[2]})`);
  if (rec.last_type && rec.last_type !== worst) parts.push(`· now ${typeText(rec.last_type)}`);
  return parts.join(" ");
}

export const ackText = (a) => (a ? `${a.by} ${clock(a.at)}` : "");

function span(className, text = "") {
  const node = document.createElement("span");
  node.className = className;
  node.textContent = text;
  return node;
}

function button(className, text, onClick) {
  const node = document.createElement("button");
  node.type = "button";
  node.className = className;
  node.textContent = text;
  node.addEventListener("click", onClick);
  return node;
}

export class Feed {
  constructor({ list, banner, bannerText, bannerAck, bannerAckAll, counter, mute, alarmsOnly,
    shelveDialog }) {
    this.list = list;
    this.banner = banner;
    this.bannerText = bannerText;
    this.bannerAck = bannerAck;
    this.bannerAckAll = bannerAckAll;
    this.counter = counter;
    this.mute = mute;
    this.alarmsOnly = alarmsOnly;
    this.shelveDialog = shelveDialog;
    this.events = new Map(); // id -> event of no incident, the ones in the feed
    this.incidents = new Map(); // id -> incident record, the ones in the feed
    this.lastEvents = new Map(); // incident id -> the newest of its events seen (bounded)
    this.zoneKinds = new Map();
    this.canAck = false;
    this.onRaised = () => {}; // told of a new incident (its record), to open its camera
    this.sound = new Alarm();
    this.sound.onChange = () => this.showSound();
    this.mute.addEventListener("click", () => this.toggleMute());
    this.bannerAck.addEventListener("click", () => {
      const first = this.unacked()[0];
      if (first) this.acknowledge(first.id);
    });
    this.bannerAckAll.addEventListener("click", () => this.acknowledgeAll());
    this.alarmsOnly.addEventListener("change", () => {
      this.list.classList.toggle("alarms-only", this.alarmsOnly.checked);
    });
    this.setUpShelving();
  }

  setRole(role) {
    this.canAck = role === "operator" || role === "admin";
    this.bannerAck.hidden = !this.canAck;
    this.rerender();
    this.update();
  }

  setZones(zones) {
    this.zoneKinds = new Map(zones.map((z) => [z.name, z.kind]));
  }

  rerender() {
    for (const li of this.list.children) {
      if (li.dataset.incidentId) this.renderIncident(this.incidents.get(Number(li.dataset.incidentId)), li);
      else this.renderEvent(this.events.get(Number(li.dataset.eventId)), li);
    }
  }

  /** The newest incidents and events at the start (each newest first), replacing what was shown. */
  reset(incidents, events) {
    this.events.clear();
    this.incidents.clear();
    this.list.replaceChildren();
    for (const rec of [...incidents].reverse()) this.incident(rec, false);
    for (const e of [...events].reverse()) this.add(e, false);
    this.update();
  }

  /** A line's place in the feed: 0 an open incident not acknowledged, 1 another open one,
   * 2 the history (closed incidents, info events). */
  rank(li) {
    const rec = li.dataset.incidentId ? this.incidents.get(Number(li.dataset.incidentId)) : null;
    if (!rec || rec.state === "closed") return 2;
    return UNACKED.has(rec.state) ? 0 : 1;
  }

  /** Where a line goes: the open incidents on top, those not acknowledged first, above the
   * history; within each, newest first by its wall time (an incident's first). */
  place(li) {
    const at = Number(li.dataset.at);
    const rank = this.rank(li);
    li.dataset.rank = String(rank);
    if (li.parentNode === this.list) li.remove();
    let next = this.list.firstElementChild;
    while (next && (Number(next.dataset.rank) < rank
                    || (Number(next.dataset.rank) === rank && Number(next.dataset.at) > at))) {
      next = next.nextElementSibling;
    }
    this.list.insertBefore(li, next);
    while (this.list.children.length > MAX_ITEMS) {
      const last = this.list.lastElementChild;
      if (last.dataset.incidentId) this.incidents.delete(Number(last.dataset.incidentId));
      else this.events.delete(Number(last.dataset.eventId));
      last.remove();
    }
  }

  /** One event from the live channel (or the start). An event of an incident is one of its
   * occurrences: its line says so (the incident's own message brings the count). */
  add(e, live = true) {
    if (!e || e.id === undefined) return;
    if (known(e.incident)) {
      // its incident's line names its newest event (the incident's message may come first)
      const newest = Math.max(e.id, this.lastEvents.get(e.incident) ?? 0);
      this.lastEvents.delete(e.incident);
      this.lastEvents.set(e.incident, newest);
      if (this.lastEvents.size > MAX_ITEMS) this.lastEvents.delete(this.lastEvents.keys().next().value);
      const li = this.lineOf(e.incident);
      if (li) li.dataset.lastEvent = String(newest);
      return;
    }
    if (this.events.has(e.id)) return;
    this.events.set(e.id, e);
    const li = document.createElement("li");
    li.dataset.eventId = String(e.id);
    li.dataset.at = String(typeof e.wall_t === "number" ? e.wall_t : 0);
    this.renderEvent(e, li);
    if (live) li.classList.add("new");
    this.place(li);
  }

  lineOf(id) {
    return this.list.querySelector(`li[data-incident-id="${Number(id)}"]`);
  }

  /** An incident's record (the start, an act's answer, or a live change): its line made or
   * redrawn. live: a change just now (a new incident flashes its line). */
  incident(rec, live = true) {
    if (!rec || !known(rec.id)) return;
    const old = this.incidents.get(rec.id);
    // a stale record (an act's answer after the live change) never undoes a newer one
    if (old && (rec.last_t ?? 0) < (old.last_t ?? 0) && rec.occurrences < old.occurrences) return;
    this.incidents.set(rec.id, rec);
    let li = this.lineOf(rec.id);
    const made = !li;
    if (made) {
      li = document.createElement("li");
      li.dataset.incidentId = String(rec.id);
      if (live) li.classList.add("new");
    }
    li.dataset.at = String(rec.first_wall_t ?? rec.first_t ?? 0);
    this.renderIncident(rec, li);
    if (made || this.rank(li) !== Number(li.dataset.rank)) this.place(li); // its state moved it
    if (live) this.update();
  }

  /** A live `incident` message: {change, before, state, notify, by, incident}. */
  change(message) {
    const rec = message && message.incident;
    if (!rec) return;
    const isNew = !this.incidents.has(rec.id);
    this.incident(rec, true);
    if (message.notify && isNew) this.onRaised(rec);
  }

  /** An event's acknowledgement, by this console or another (the live channel's ack message). */
  acked(id, a) {
    const e = this.events.get(id);
    if (!e) return;
    if (!e.ack) e.ack = a;
    const li = this.list.querySelector(`li[data-event-id="${id}"]`);
    if (li) this.renderEvent(e, li);
  }

  renderEvent(e, li) {
    if (!e) return;
    const level = e.level || "info";
    li.className = `event level-${level}${e.ack ? " acked" : ""}${li.classList.contains("new") ? " new" : ""}`;
    li.dataset.type = e.type;
    li.dataset.level = level;
    if (e.zone) li.dataset.zone = e.zone;
    if (known(e.person)) li.dataset.person = String(e.person);
    const time = document.createElement("time");
    time.textContent = clock(e.wall_t);
    time.dateTime = typeof e.wall_t === "number" ? new Date(e.wall_t * 1000).toISOString() : "";
    const badge = span(`level level-${level}`, level);
    const what = span("what", describe(e));
    const tail = span("ack-state", e.ack ? `ack ${ackText(e.ack)}` : "");
    li.replaceChildren(time, badge, what, tail);
  }

  renderIncident(rec, li) {
    if (!rec) return;
    const p = Number(rec.priority) || 4;
    const unacked = UNACKED.has(rec.state);
    li.className = ["event", "incident", `priority-${p}`, `state-${rec.state}`,
      "level-alarm", // every incident is an alarm's or a warning's: "alarms only" shows it
      rec.shelved ? "shelved" : "", rec.first_out ? "first-out" : "",
      unacked ? "" : "acked", li.classList.contains("new") ? "new" : ""].filter(Boolean).join(" ");
    li.dataset.state = rec.state;
    li.dataset.priority = String(p);
    li.dataset.count = String(rec.occurrences);
    li.dataset.shelved = String(!!rec.shelved);
    li.dataset.type = rec.type;
    li.dataset.worst = rec.worst_type || rec.type;
    if (rec.zone) li.dataset.zone = rec.zone;
    if (known(rec.person)) li.dataset.person = String(rec.person);
    if (rec.camera) li.dataset.camera = rec.camera;
    if (known(rec.first_event)) li.dataset.firstEvent = String(rec.first_event);
    const lastEvent = Math.max(rec.last_event ?? 0, this.lastEvents.get(rec.id) ?? 0);
    if (lastEvent) li.dataset.lastEvent = String(lastEvent);
    const time = document.createElement("time");
    const first = rec.first_wall_t;
    time.textContent = clock(first);
    time.dateTime = typeof first === "number" ? new Date(first * 1000).toISOString() : "";
    const badge = span(`level priority priority-${p}`, `P${p} ${PRIORITY_NAMES[p] || ""}`.trim());
    badge.title = `priority ${p}`;
    const what = span("what", describeIncident(rec, this.zoneKinds));
    if (rec.occurrences > 1) {
      const count = span("count", `×${rec.occurrences}`);
      count.title = `${rec.occurrences} occurrences, the last at ${clock(rec.last_wall_t)}`;
      what.append(" ", count);
    }
    if (rec.first_out) what.prepend(span("first-out-mark", "FIRST OUT"), " ");
    const tail = span("ack-state");
    tail.append(span("state-label", STATE_TEXT[rec.state] || rec.state));
    if (rec.acked_by) tail.append(` · ack ${rec.acked_by} ${clock(rec.acked_wall_at)}`);
    if (rec.shelved) {
      const until = clock(rec.shelved_wall_until);
      const shelved = span("shelved-label", `shelved until ${until}`);
      shelved.title = `by ${rec.shelved_by || "?"}: ${rec.shelved_reason || ""}`;
      tail.append(" · ", shelved);
    }
    if (this.canAck && unacked) {
      tail.append(" ", button("ack-button", "Ack", () => this.acknowledge(rec.id)));
    }
    if (this.canAck && rec.state !== "closed" && !rec.shelved) {
      tail.append(" ", button("shelve-button", "Shelve", () => this.askShelve(rec.id)));
    }
    if (!this.canAck && unacked) tail.append(" · not acknowledged");
    li.replaceChildren(time, badge, what, tail);
  }

  async acknowledge(id) {
    try {
      const answer = await ackIncident(id);
      this.incident(answer.incident);
    } catch (error) {
      this.failed(id, "ack", error);
    }
  }

  failed(id, what, error) {
    if (error instanceof ApiError && error.status === 401) return; // the login is shown
    const state = this.lineOf(id)?.querySelector(".ack-state");
    if (state) state.textContent = `${what} failed: ${error.detail || error.message}`;
  }

  // -- shelving: a small form asking why and for how long
  setUpShelving() {
    const d = this.shelveDialog;
    if (!d) return;
    const select = d.querySelector("#shelve-duration");
    for (const [seconds, text] of SHELVE_CHOICES) {
      const option = document.createElement("option");
      option.value = String(seconds);
      option.textContent = text;
      select.appendChild(option);
    }
    d.querySelector("#shelve-cancel").addEventListener("click", () => d.close());
    d.querySelector("form").addEventListener("submit", async (event) => {
      event.preventDefault();
      const id = Number(d.dataset.incidentId);
      const reason = d.querySelector("#shelve-reason").value.trim();
      const error = d.querySelector("#shelve-error");
      if (!reason) {
        error.textContent = "Say why it is shelved.";
        return;
      }
      try {
        const answer = await shelveIncident(id, reason, Number(select.value));
        this.incident(answer.incident);
        d.close();
      } catch (e) {
        if (e instanceof ApiError && e.status === 401) return;
        error.textContent = `Shelving failed: ${e.detail || e.message}`;
      }
    });
  }

  askShelve(id) {
    const d = this.shelveDialog;
    const rec = this.incidents.get(id);
    if (!d || !rec) return;
    d.dataset.incidentId = String(id);
    d.querySelector("#shelve-what").textContent = describeIncident(rec, this.zoneKinds);
    d.querySelector("#shelve-reason").value = "";
    d.querySelector("#shelve-error").textContent = "";
    d.showModal();
    d.querySelector("#shelve-reason").focus();
  }

  /** The newest event id shown (0 when none): where a reconnection's catch-up starts. */
  newestId() {
    let newest = 0;
    for (const id of this.events.keys()) newest = Math.max(newest, id);
    for (const rec of this.incidents.values()) newest = Math.max(newest, rec.last_event ?? 0);
    for (const id of this.lastEvents.values()) newest = Math.max(newest, id);
    return newest;
  }

  /** Every unacknowledged incident of the feed, the most urgent first, one request at a time. */
  async acknowledgeAll() {
    this.bannerAckAll.disabled = true;
    try {
      for (const rec of this.unacked()) await this.acknowledge(rec.id);
    } finally {
      this.bannerAckAll.disabled = false;
    }
  }

  /** The banner's incidents: unacknowledged and not shelved, by priority, then newest. */
  unacked() {
    return [...this.incidents.values()]
      .filter((rec) => UNACKED.has(rec.state) && !rec.shelved)
      .sort((a, b) => a.priority - b.priority || (b.first_wall_t ?? 0) - (a.first_wall_t ?? 0) || b.id - a.id);
  }

  update() {
    const open = this.unacked();
    this.counter.textContent = String(open.length);
    this.counter.classList.toggle("active", open.length > 0);
    this.banner.hidden = open.length === 0;
    document.body.classList.toggle("alarm-active", open.length > 0);
    this.bannerAckAll.hidden = !this.canAck || open.length < 2;
    this.bannerAckAll.textContent = `Acknowledge all ${open.length}`;
    if (open.length) {
      const first = open[0];
      const p = Number(first.priority) || 4;
      this.banner.dataset.priority = String(p);
      this.banner.dataset.incidentId = String(first.id);
      this.banner.dataset.state = first.state;
      this.bannerText.textContent = `P${p} ${clock(first.first_wall_t)} ${describeIncident(first, this.zoneKinds)}` +
        (first.state === "cleared" ? " (cleared)" : "") +
        (open.length > 1 ? ` (+${open.length - 1} more)` : "");
    }
    // the sound while an incident is active and unacknowledged (a cleared one only shows)
    this.sound.sounding(open.some((rec) => rec.state === "active"));
    this.showSound();
  }

  showSound() {
    const muted = this.sound.muted;
    // after a reload the browser holds the sound back until the page is clicked once
    this.mute.textContent = muted ? "Sound muted" : this.sound.blocked() ? "Click for sound" : "Sound on";
    this.mute.setAttribute("aria-pressed", String(muted));
    this.mute.classList.toggle("muted", muted);
    this.mute.classList.toggle("blocked", this.sound.blocked());
  }

  toggleMute() {
    // the click that let the sound start (its pointerdown unlocked it) is not a mute
    if (this.sound.blocked() || performance.now() - this.sound.unlockedAt < 1000) {
      this.sound.unlock();
      return;
    }
    this.sound.mute(!this.sound.muted);
    this.showSound();
  }

  /** Called from a click or key press: the browser lets the sound start only after one. */
  unlockSound() {
    this.sound.unlock();
  }
}
