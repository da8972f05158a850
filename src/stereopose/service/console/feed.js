// The alarm feed, newest first, and what makes a new alarm unmistakable until someone
// acknowledges it: the flashing banner, the counter, the sound (which can be muted).

import { ack, ApiError } from "./api.js";
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
};

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

/** "person 3 entered overhead_busbar (energized)", the words of one event. */
export function describe(e) {
  const parts = [];
  if (e.person !== null && e.person !== undefined && e.person >= 0) parts.push(`person ${e.person}`);
  parts.push(typeText(e.type));
  if (e.zone) parts.push(e.zone);
  if (e.kind && e.zone && e.kind !== e.zone) parts.push(`(${e.kind})`);
  if (e.rule) parts.push(`(rule ${e.rule})`);
  if (e.camera && !String(e.type).startsWith("camera")) parts.push(`· ${e.camera}`);
  else if (e.camera && !e.zone) parts.push(e.camera);
  return parts.join(" ");
}

export const ackText = (a) => (a ? `${a.by} ${clock(a.at)}` : "");

export class Feed {
  constructor({ list, banner, bannerText, bannerAck, bannerAckAll, counter, mute, alarmsOnly }) {
    this.list = list;
    this.banner = banner;
    this.bannerText = bannerText;
    this.bannerAck = bannerAck;
    this.bannerAckAll = bannerAckAll;
    this.counter = counter;
    this.mute = mute;
    this.alarmsOnly = alarmsOnly;
    this.events = new Map(); // id -> event, the ones in the feed
    this.canAck = false;
    this.sound = new Alarm();
    this.sound.onChange = () => this.showSound();
    this.mute.addEventListener("click", () => this.toggleMute());
    this.bannerAck.addEventListener("click", () => {
      const newest = this.unacked()[0];
      if (newest) this.acknowledge(newest.id);
    });
    this.bannerAckAll.addEventListener("click", () => this.acknowledgeAll());
    this.alarmsOnly.addEventListener("change", () => {
      this.list.classList.toggle("alarms-only", this.alarmsOnly.checked);
    });
  }

  setRole(role) {
    this.canAck = role === "operator" || role === "admin";
    this.bannerAck.hidden = !this.canAck;
    this.update();
    for (const li of this.list.children) this.render(this.events.get(Number(li.dataset.eventId)), li);
  }

  /** The newest events at the start (newest first), replacing what was shown. */
  reset(events) {
    this.events.clear();
    this.list.replaceChildren();
    for (const e of [...events].reverse()) this.add(e, false);
    this.update();
  }

  /** One event from the live channel (or the start), put at the top. */
  add(e, live = true) {
    if (!e || e.id === undefined || this.events.has(e.id)) return;
    this.events.set(e.id, e);
    const li = document.createElement("li");
    li.dataset.eventId = String(e.id);
    this.render(e, li);
    if (live) li.classList.add("new");
    // newest first by id: a late one (fetched after a reconnection) goes to its place
    let next = this.list.firstElementChild;
    while (next && Number(next.dataset.eventId) > e.id) next = next.nextElementSibling;
    this.list.insertBefore(li, next);
    while (this.list.children.length > MAX_ITEMS) {
      const last = this.list.lastElementChild;
      this.events.delete(Number(last.dataset.eventId));
      last.remove();
    }
    if (live) this.update();
  }

  /** An acknowledgement, by this console or another (the live channel's ack message). */
  acked(id, a) {
    const e = this.events.get(id);
    if (!e) return;
    if (!e.ack) e.ack = a;
    const li = this.list.querySelector(`li[data-event-id="${id}"]`);
    if (li) this.render(e, li);
    this.update();
  }

  render(e, li) {
    if (!e) return;
    const level = e.level || "info";
    li.className = `event level-${level}${e.ack ? " acked" : ""}${li.classList.contains("new") ? " new" : ""}`;
    li.dataset.type = e.type;
    li.dataset.level = level;
    if (e.zone) li.dataset.zone = e.zone;
    if (e.person !== null && e.person !== undefined) li.dataset.person = String(e.person);
    const time = document.createElement("time");
    time.textContent = clock(e.wall_t);
    time.dateTime = typeof e.wall_t === "number" ? new Date(e.wall_t * 1000).toISOString() : "";
    const what = document.createElement("span");
    what.className = "what";
    what.textContent = describe(e);
    const badge = document.createElement("span");
    badge.className = `level level-${level}`;
    badge.textContent = level;
    const tail = document.createElement("span");
    tail.className = "ack-state";
    if (e.ack) {
      tail.textContent = `ack ${ackText(e.ack)}`;
    } else if (level === "alarm" && this.canAck) {
      const button = document.createElement("button");
      button.type = "button";
      button.className = "ack-button";
      button.textContent = "Ack";
      button.addEventListener("click", () => this.acknowledge(e.id));
      tail.appendChild(button);
    } else if (level === "alarm") {
      tail.textContent = "not acknowledged";
    }
    li.replaceChildren(time, badge, what, tail);
  }

  async acknowledge(id) {
    try {
      const answer = await ack(id);
      this.acked(answer.id, answer.ack);
    } catch (error) {
      if (error instanceof ApiError && error.status === 401) return; // the login is shown
      const li = this.list.querySelector(`li[data-event-id="${id}"] .ack-state`);
      if (li) li.textContent = `ack failed: ${error.detail || error.message}`;
    }
  }

  /** The newest event id shown (0 when none). */
  newestId() {
    const first = this.list.firstElementChild;
    return first ? Number(first.dataset.eventId) : 0;
  }

  /** Every unacknowledged alarm of the feed, newest first, one request at a time. */
  async acknowledgeAll() {
    this.bannerAckAll.disabled = true;
    try {
      for (const e of this.unacked()) await this.acknowledge(e.id);
    } finally {
      this.bannerAckAll.disabled = false;
    }
  }

  unacked() {
    return [...this.events.values()]
      .filter((e) => e.level === "alarm" && !e.ack)
      .sort((a, b) => b.id - a.id);
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
      const newest = open[0];
      this.bannerText.textContent = `${clock(newest.wall_t)} ${describe(newest)}` +
        (open.length > 1 ? ` (+${open.length - 1} more)` : "");
    }
    this.sound.sounding(open.length > 0);
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
