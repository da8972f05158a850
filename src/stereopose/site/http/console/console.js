// The operator console: the login, then the live floor plan, the alarm feed, the cameras, the
// 3D view and the history, fed by the API's first answers and then by the live channel.

import * as api from "./api.js";
import { CameraStrip } from "./cameras.js";
import { byId } from "./dom.js";
import { describeIncident, Feed } from "./feed.js";
import { FloorPlan } from "./floorplan.js";
import { History } from "./history.js";
import { ENDED, Login } from "./login.js";
import { OnSitePanel } from "./onsite.js";
import { Replay } from "./replay.js";
import { SiteEditor } from "./site.js";
import { Tickets } from "./tickets.js";
import { View3D } from "./view3d.js";

const RATES_MS = 10_000;
const ONSITE_MS = 2_000; // what sounds on site: asked this often

function insidePolygon([x, y], polygon) {
  let inside = false;
  for (let i = 0, j = polygon.length - 1; i < polygon.length; j = i++) {
    const [xi, yi] = polygon[i];
    const [xj, yj] = polygon[j];
    if ((yi > y) !== (yj > y) && x < ((xj - xi) * (y - yi)) / (yj - yi) + xi) inside = !inside;
  }
  return inside;
}

class Console {
  constructor() {
    this.user = null;
    this.cameras = [];
    this.zones = [];
    this.floor = new FloorPlan(byId("floor"), byId("floor-info"));
    this.strip = new CameraStrip(byId("cameras"), {
      dialog: byId("camera-view"), img: byId("camera-view-picture"), title: byId("camera-view-title"),
      why: byId("camera-view-why"), close: byId("camera-view-close"),
    });
    const regionsToggle = byId("regions-toggle");
    regionsToggle.addEventListener("click", () => {
      const on = regionsToggle.getAttribute("aria-pressed") !== "true";
      regionsToggle.setAttribute("aria-pressed", String(on));
      this.strip.showRegions(on);
    });
    this.view3d = new View3D(byId("view3d"), byId("view3d-info"));
    this.replay = new Replay();
    this.history = new History(this.replay);
    this.tickets = new Tickets(this.replay);
    this.site = new SiteEditor();
    this.onsite = new OnSitePanel(byId("onsite"));
    this.feed = new Feed({
      list: byId("feed"), banner: byId("alarm-banner"), bannerText: byId("alarm-text"),
      bannerAck: byId("alarm-ack"), bannerAckAll: byId("alarm-ack-all"), counter: byId("alarm-count"), mute: byId("mute"),
      alarmsOnly: byId("feed-alarms-only"), shelveDialog: byId("shelve-dialog"),
    });
    this.feed.onRaised = (rec) => this.onRaised(rec);
    this.ratesTimer = null;
    this.onsiteTimer = null;
    this.live = new api.Live({
      people: (body) => this.onPeople(body),
      event: (e) => this.feed.add(e),
      incident: (message) => this.onIncident(message),
      closed: (body) => this.onClosed(body),
      zones: (body) => this.onZones(body.zones || []),
      cameras: (body) => this.onCameras(body.cameras || []),
      ack: (body) => this.feed.acked(body.id, body.ack),
      logout: () => this.login.show(ENDED),
    }, (up) => this.onLink(up));
    this.tab = "live";
    this.linkWasDown = false;
    this.pendingPeople = null;
    this.staleTimer = null;
    this.login = new Login({
      enter: (user) => this.enter(user),
      leave: () => this.leave(),
      settle: () => this.settle(),
      beforeSubmit: () => this.feed.unlockSound(), // the login's click lets the sound start
    });
    byId("link").addEventListener("click", () => {
      if (this.user && byId("link").classList.contains("ended")) this.live.start();
    });
    for (const tab of document.querySelectorAll(".tab")) {
      tab.addEventListener("click", () => this.showTab(tab.dataset.tab));
    }
    // the browser lets the alarm sound start only after a gesture
    for (const kind of ["pointerdown", "keydown"]) {
      document.addEventListener(kind, () => this.feed.unlockSound(), { passive: true });
    }
  }

  start() {
    return this.login.start();
  }

  /** Everything the console asks stopped, its panels hidden (the login is shown). */
  leave() {
    this.live.stop();
    clearInterval(this.staleTimer);
    clearInterval(this.ratesTimer);
    clearInterval(this.onsiteTimer);
    this.strip.show(false);
    this.strip.closeLarge();
    this.view3d.show(false);
    this.tickets.show(false);
    this.history.show(false);
    this.replay.close();
    this.feed.sound.sounding(false);
    this.user = null;
  }

  /** Before a logout: nothing more asked with this session, the pictures in flight let land. */
  async settle() {
    this.live.stop();
    clearInterval(this.ratesTimer);
    clearInterval(this.onsiteTimer);
    this.strip.show(false);
    await this.strip.idle();
    await this.ratesPending;
    await this.onsite.pending;
  }

  async enter(user) {
    this.user = user;
    this.feed.setRole(user.role);
    this.tickets.setRole(user.role);
    this.site.setRole(user.role);
    this.onsite.setRole(user.role);
    this.live.start();
    this.showTab(this.tab);
    clearInterval(this.staleTimer);
    this.staleTimer = setInterval(() => this.checkStale(), 1000);
    clearInterval(this.ratesTimer);
    this.ratesTimer = setInterval(() => { this.showRates(); this.showCalibration(); }, RATES_MS);
    clearInterval(this.onsiteTimer);
    this.onsiteTimer = setInterval(() => this.onsite.refresh(), ONSITE_MS);
    this.onsite.refresh();
    this.strip.onAccept = (camera) => this.acceptPose(camera);
    this.showCalibration();
    try {
      const [cameras, zones, events, incidents, people] = await Promise.all([
        api.cameras(), api.zones(), api.events({ limit: 100 }), api.incidents({ limit: 100 }),
        api.people(),
      ]);
      this.onCameras(cameras.cameras || [], true);
      this.onZones(zones.zones || []);
      this.feed.reset(incidents.incidents || [], events.events || []);
      this.onPeople(people);
      this.showRates();
      this.history.search();
    } catch (error) {
      if (!(error instanceof api.ApiError && error.status === 401)) {
        byId("floor-info").textContent = `not loaded: ${error.detail || error.message}`;
      }
    }
  }

  /** People at up to 5 a second: drawn at the next animation frame, only the newest, so the
   * drawing never queues up ahead of an alarm. */
  onPeople(body) {
    this.view3d.setPeople(body.people || []);
    this.tickets.setPeople(body.people || []);
    const pending = this.pendingPeople;
    this.pendingPeople = body;
    if (pending) return;
    requestAnimationFrame(() => {
      const newest = this.pendingPeople;
      this.pendingPeople = null;
      this.floor.setPeople(newest);
    });
  }

  onZones(zones) {
    this.zones = zones;
    this.feed.setZones(zones);
    this.floor.setZones(zones);
    this.view3d.setZones(zones);
    this.history.setZones(zones);
    this.tickets.setZones(zones);
    this.replay.setZones(zones);
  }

  /** All of /api/cameras at the start; later the live channel's health (maybe only that). */
  onCameras(cameras, full = false) {
    const known = new Set(this.cameras.map((c) => c.name));
    const complete = cameras.every((c) => Array.isArray(c.position));
    if (full || (complete && cameras.some((c) => !known.has(c.name)))) {
      this.cameras = cameras;
      this.floor.setCameras(cameras);
      this.strip.setCameras(cameras);
    } else {
      const byName = new Map(cameras.map((c) => [c.name, c.health]));
      for (const cam of this.cameras) if (byName.get(cam.name)) cam.health = byName.get(cam.name);
      for (const [name, health] of byName) this.strip.setHealth(name, health);
      for (const cam of cameras) if ("regions" in cam) this.strip.setRegions(cam.name, cam.regions);
      for (const cam of cameras) this.strip.setLight(cam.name, cam.light);
      this.floor.setHealth(byName);
    }
    this.view3d.setCameras(this.cameras);
  }

  /** A live incident change: its feed line, and the alarm-rate panel when one is raised. */
  onIncident(message) {
    this.feed.change(message);
    if (message && message.change === "raised") this.showRates();
  }

  /** A new incident (a sound and a banner): its camera opened large, on the live tab, unless
   * the large view shows a more urgent incident not yet acknowledged. */
  onRaised(rec) {
    if (this.tab !== "live") return;
    const shown = this.feed.incidents.get(Number(byId("camera-view").dataset.incident));
    if (byId("camera-view").open && shown && shown.priority < rec.priority
      && ["active", "cleared"].includes(shown.state)) return;
    const camera = this.cameraFor(rec);
    if (camera) this.strip.open(camera, `alarm: ${describeIncident(rec, this.feed.zoneKinds)}`, rec.id);
  }

  /** The camera that best shows an incident: its own (a camera's incident), else the up
   * camera nearest to the person (or the zone) among those whose view on the floor holds it. */
  cameraFor(rec) {
    if (rec.camera) return this.cameras.some((c) => c.name === rec.camera) ? rec.camera : null;
    let point = null;
    const person = (this.floor.people || []).find((p) => p.id === rec.person);
    if (person && Array.isArray(person.position)) point = person.position;
    const zone = this.zones.find((z) => z.name === rec.zone);
    if (!point && zone && zone.polygon && zone.polygon.length) {
      point = zone.polygon.reduce((a, p) => [a[0] + p[0] / zone.polygon.length, a[1] + p[1] / zone.polygon.length], [0, 0]);
    }
    const up = this.cameras.filter((c) => Array.isArray(c.position) && (!c.health || c.health.state !== "down"));
    if (!up.length) return null;
    if (!point) return up[0].name;
    const distance = (c) => Math.hypot(c.position[0] - point[0], c.position[1] - point[1]);
    const seeing = up.filter((c) => Array.isArray(c.floor_fov) && c.floor_fov.length >= 3 && insidePolygon(point, c.floor_fov));
    const pool = seeing.length ? seeing : up;
    return pool.reduce((best, c) => (distance(c) < distance(best) ? c : best)).name;
  }

  /** The alarm-rate panel: the operator's load against the flood line (api /api/alarm-rates). */
  showRates() {
    // kept, so that a logout lets the one in flight land before the session ends
    this.ratesPending = this.fetchRates();
    return this.ratesPending;
  }

  /** Each camera's calibration as the keeper has it: being placed again, a pose proposed for
   * an admin to accept, or not corrected and why (api /api/calibration). */
  async showCalibration() {
    let body;
    try {
      body = await api.calibration();
    } catch {
      return; // the next period tries again
    }
    this.strip.setCalibration(body.running ? body : null, this.user ? this.user.role : "viewer");
  }

  /** An admin accepts the pose proposed for `camera`: applied by the service at its next step. */
  async acceptPose(camera) {
    try {
      await api.acceptPose(camera);
    } catch (error) {
      this.strip.setCalibrationError(camera, error.detail || error.message);
      return;
    }
    await this.showCalibration();
  }

  async fetchRates() {
    let r;
    try {
      r = await api.alarmRates();
    } catch {
      return; // the next period tries again
    }
    const panel = byId("rates");
    if (!r.running) {
      panel.dataset.running = "false";
      return;
    }
    panel.dataset.running = "true";
    byId("rate-10min").textContent = String(r.notifications_10min);
    byId("rate-1h").textContent = String(r.notifications_1h);
    byId("rate-flood").textContent = String(r.flood_line);
    byId("rate-chattering").textContent = String(r.chattering);
    byId("rate-standing").textContent = String(r.standing);
    byId("rate-shelved").textContent = String(r.shelved ?? 0);
    panel.classList.toggle("flood", !!r.flood);
    panel.classList.toggle("chattering", r.chattering > 0);
  }

  /** The server ended this page's live channel for another of the user's (too many open): it
   * stays closed until the operator asks for it again, so two pages never take turns. */
  onClosed(body) {
    this.live.stop();
    const link = byId("link");
    link.textContent = "ended: click to reconnect";
    link.title = body && body.reason ? String(body.reason) : "the live channel was ended";
    link.className = "link link-down ended";
  }

  onLink(up) {
    if (up && this.linkWasDown && this.user) this.catchUp();
    this.linkWasDown = !up;
    const link = byId("link");
    link.textContent = up ? "live" : "reconnecting";
    link.className = `link ${up ? "link-up" : "link-down"}`;
  }

  /** The events and incident changes the feed missed while the live channel was down. */
  async catchUp() {
    const after = this.feed.newestId();
    try {
      const [events, incidents] = await Promise.all([
        after ? api.events({ after_id: after, limit: 1000 }) : { events: [] },
        api.incidents({ limit: 100 }),
      ]);
      for (const e of [...(events.events || [])].reverse()) this.feed.add(e);
      for (const rec of [...(incidents.incidents || [])].reverse()) this.feed.incident(rec, false);
      this.feed.update();
    } catch {
      // the next reconnection tries again
    }
  }

  checkStale() {
    const age = this.floor.age();
    byId("floor").classList.toggle("stale", age > 3);
    if (age > 3 && Number.isFinite(age)) byId("floor-info").textContent = `no live data for ${age.toFixed(0)} s`;
  }

  showTab(name) {
    this.tab = name;
    for (const tab of document.querySelectorAll(".tab")) {
      const active = tab.dataset.tab === name;
      tab.classList.toggle("active", active);
      tab.setAttribute("aria-selected", String(active));
    }
    for (const page of document.querySelectorAll(".tab-page")) {
      page.hidden = page.id !== `tab-${name}`;
    }
    this.strip.show(name === "live");
    this.view3d.show(name === "view3d");
    this.tickets.show(name === "tickets" && !!this.user);
    this.history.show(name === "history" && !!this.user);
    if (name === "history" && this.user) this.history.search();
    if (name === "site" && this.user) this.site.show(true);
  }
}

const app = new Console();
window.stereoposeConsole = app; // for an operator's browser console, and the page's tests
app.start();
