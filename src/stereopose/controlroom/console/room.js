// The control room's console: the login (the site console's), every site at a glance, one
// incident feed across sites with Ack, and a site's plan with its people now. It asks the
// control room's API every POLL_MS; a site's page asks for its people every PLAN_MS.

import * as api from "/console/api.js";
import { byId } from "/console/dom.js";
import { Login } from "/console/login.js";

const POLL_MS = 2000;
const PLAN_MS = 1000;
const PRIORITY = { 1: "critical", 2: "high", 3: "medium", 4: "low" };
const SVG = "http://www.w3.org/2000/svg";

function el(tag, attrs = {}, text = null) {
  const node = tag.startsWith("svg:") ? document.createElementNS(SVG, tag.slice(4))
    : document.createElement(tag);
  for (const [key, value] of Object.entries(attrs)) node.setAttribute(key, value);
  if (text !== null) node.textContent = text;
  return node;
}

function ago(t) {
  if (t === null || t === undefined) return "never";
  const s = Math.max(0, Date.now() / 1000 - t);
  if (s < 60) return `${Math.round(s)} s ago`;
  if (s < 3600) return `${Math.round(s / 60)} min ago`;
  return new Date(t * 1000).toLocaleString();
}

function clock(t) {
  return t ? new Date(t * 1000).toLocaleTimeString([], { hour12: false }) : "";
}

/** What an incident is about, in words. */
function about(inc) {
  if (inc.source === "control_room") return inc.detail || inc.kind;
  const what = inc.zone ? `zone ${inc.zone}` : inc.rule ? `rule ${inc.rule}`
    : inc.camera ? `camera ${inc.camera}` : inc.kind || "service";
  const who = inc.person !== null && inc.person !== undefined && inc.person >= 0
    ? `, person ${inc.person}` : "";
  const times = inc.occurrences > 1 ? ` (${inc.occurrences}\u00d7)` : "";
  return `${what}${who}${times}`;
}

class Room {
  constructor() {
    this.user = null;
    this.site = null;
    this.timer = null;
    this.planTimer = null;
    this.login = new Login({
      enter: (user) => this.enter(user),
      leave: () => this.leave(),
      settle: async () => this.stop(),
    });
    for (const tab of document.querySelectorAll(".tab")) {
      tab.addEventListener("click", () => this.showTab(tab.dataset.tab));
    }
  }

  start() {
    return this.login.start();
  }

  /** Nothing more asked of the API (a logout, or the login shown). */
  stop() {
    clearInterval(this.timer);
    clearInterval(this.planTimer);
  }

  leave() {
    this.stop();
    this.user = null;
  }

  enter(user) {
    this.user = user;
    this.showTab("sites");
    clearInterval(this.timer);
    this.timer = setInterval(() => this.refresh(), POLL_MS);
    this.refresh();
  }

  showTab(name) {
    for (const tab of document.querySelectorAll(".tab")) {
      tab.classList.toggle("active", tab.dataset.tab === name);
    }
    byId("tab-sites").classList.toggle("active", name === "sites");
    byId("tab-site").classList.toggle("active", name === "site");
    clearInterval(this.planTimer);
    if (name === "site" && this.site) {
      this.planTimer = setInterval(() => this.showPlan(), PLAN_MS);
      this.showPlan();
    }
  }

  link(up) {
    const link = byId("link");
    link.textContent = up ? "live" : "no answer";
    link.classList.toggle("link-up", up);
    link.classList.toggle("link-down", !up);
  }

  async refresh() {
    if (!this.user) return;
    try {
      const [sites, incidents] = await Promise.all([
        api.call("/api/sites"), api.call("/api/incidents?state=open&limit=500"),
      ]);
      this.link(true);
      this.showSites(sites.sites);
      this.incidents = incidents.incidents;
      this.showFeed(byId("room-feed"), this.incidents);
      if (this.site) {
        this.showFeed(byId("site-feed"), this.incidents.filter((i) => i.site === this.site));
      }
      const unacked = this.incidents.filter((i) => !i.acked_by && i.state !== "closed").length;
      const count = byId("alarm-count");
      count.textContent = String(unacked);
      count.classList.toggle("active", unacked > 0);
      byId("feed-info").textContent = `${this.incidents.length} open`;
    } catch (error) {
      if (!(error instanceof api.ApiError && error.status === 401)) this.link(false);
    }
  }

  showSites(sites) {
    const body = byId("sites-body");
    body.replaceChildren();
    const states = {};
    for (const s of sites) {
      states[s.state] = (states[s.state] || 0) + 1;
      const row = el("tr", { class: "site-row", "data-site": s.site });
      row.append(el("td", {}, s.site));
      const state = el("td");
      state.append(el("span", { class: `state state-${s.state}` }, s.state));
      row.append(state);
      const open = el("td", { class: "open" });
      for (const p of ["1", "2", "3", "4"]) {
        const n = (s.open_by_priority || {})[p];
        if (n) open.append(el("span", { class: `chip p${p}`, title: PRIORITY[p] }, String(n)));
      }
      if (!open.childNodes.length) open.textContent = "0";
      row.append(open);
      row.append(el("td", {}, s.people ?? "\u2013"));
      row.append(el("td", {}, s.cameras === null || s.cameras === undefined ? "\u2013"
        : `${s.cameras_up}/${s.cameras}`));
      const off = s.clock_offset_s;
      row.append(el("td", {}, off === null || off === undefined ? "\u2013"
        : `${off >= 0 ? "+" : ""}${off.toFixed(1)} s`));
      row.append(el("td", {}, ago(s.last_seen)));
      row.addEventListener("click", () => this.openSite(s.site));
      body.append(row);
    }
    byId("sites-info").textContent = Object.entries(states).map(([k, n]) => `${n} ${k}`)
      .join(", ");
  }

  showFeed(list, incidents) {
    list.replaceChildren();
    for (const inc of incidents) {
      const state = inc.state || "active";
      const item = el("li", {
        class: `event incident level-alarm priority-${inc.priority} state-${state}`
          + (inc.acked_by ? " acked" : ""),
        "data-site": inc.site,
        "data-incident": String(inc.id),
        "data-source": inc.source,
      });
      item.append(el("time", {}, clock(inc.last_wall_t || inc.first_wall_t)));
      item.append(el("span", { class: `level priority priority-${inc.priority}` },
        PRIORITY[inc.priority] || `p${inc.priority}`));
      const what = el("span", { class: "what" });
      what.append(el("span", { class: "site-name" }, inc.site));
      what.append(document.createTextNode(`${about(inc)} \u2013 ${state}`));
      item.append(what);
      const ack = el("span", { class: "ack-state" });
      if (inc.acked_by) {
        ack.textContent = `acknowledged by ${inc.acked_by}`;
      } else if (inc.ack_pending && inc.ack_pending.length) {
        ack.append(el("span", { class: "pending" },
          `acknowledgement by ${inc.ack_pending[0].by} on its way to the site`));
      } else if (this.user && this.user.role !== "viewer") {
        const button = el("button", { class: "ack-button", type: "button" }, "Ack");
        button.addEventListener("click", (e) => {
          e.stopPropagation();
          this.ack(inc, button);
        });
        ack.append(button);
      }
      item.append(ack);
      list.append(item);
    }
  }

  async ack(inc, button) {
    button.disabled = true;
    const path = inc.source === "control_room"
      ? `/api/room-incidents/${encodeURIComponent(inc.id)}/ack`
      : `/api/sites/${encodeURIComponent(inc.site)}/incidents/${encodeURIComponent(inc.id)}/ack`;
    try {
      await api.call(path, { method: "POST" });
    } catch (error) {
      button.disabled = false;
      button.title = error.detail || error.message;
    }
    this.refresh();
  }

  openSite(site) {
    this.site = site;
    byId("site-tab").hidden = false;
    byId("site-tab").textContent = site;
    byId("site-title").textContent = site;
    byId("site-zones").replaceChildren();
    byId("site-people").replaceChildren();
    this.planKey = null;
    this.showFeed(byId("site-feed"), (this.incidents || []).filter((i) => i.site === site));
    this.showTab("site");
  }

  async showPlan() {
    const site = this.site;
    let answer;
    try {
      answer = await api.call(`/api/sites/${encodeURIComponent(site)}/plan`);
    } catch {
      return;
    }
    if (site !== this.site) return;
    const consoleLink = byId("site-console");
    if (answer.console_url && /^https?:\/\//.test(answer.console_url)) {
      consoleLink.href = answer.console_url;
      consoleLink.hidden = false;
    } else {
      consoleLink.hidden = true;
    }
    const zones = (answer.plan && answer.plan.zones) || [];
    const key = JSON.stringify(zones);
    if (key !== this.planKey) {
      this.planKey = key;
      this.drawZones(zones);
    }
    const people = (answer.people && answer.people.people) || [];
    const group = byId("site-people");
    group.replaceChildren();
    for (const p of people) {
      if (!Array.isArray(p.position)) continue;
      const [x, y] = p.position;
      const g = el("svg:g", { class: "person", "data-person": String(p.id) });
      g.append(el("svg:circle", { class: "room-person", cx: x, cy: -y, r: 0.25 }));
      g.append(el("svg:text", { class: "room-label", x, y: -y - 0.35 }, String(p.id)));
      group.append(g);
    }
    byId("site-info").textContent = answer.people
      ? `${people.length} people, ${ago(answer.people.received_at)}` : "no people message yet";
  }

  drawZones(zones) {
    const group = byId("site-zones");
    group.replaceChildren();
    let [x0, y0, x1, y1] = [-5, -5, 5, 5];
    const xs = [];
    const ys = [];
    for (const z of zones) {
      if (!Array.isArray(z.polygon)) continue;
      const points = z.polygon.map(([x, y]) => `${x},${-y}`).join(" ");
      const g = el("svg:g", { class: "zone", "data-zone": z.name });
      g.append(el("svg:polygon", { class: `room-zone kind-${z.kind}`, points }));
      const cx = z.polygon.reduce((a, p) => a + p[0], 0) / z.polygon.length;
      const cy = z.polygon.reduce((a, p) => a + p[1], 0) / z.polygon.length;
      g.append(el("svg:text", { class: "room-label", x: cx, y: -cy }, z.name));
      group.append(g);
      for (const [x, y] of z.polygon) {
        xs.push(x);
        ys.push(-y);
      }
    }
    if (xs.length) {
      [x0, x1, y0, y1] = [Math.min(...xs) - 2, Math.max(...xs) + 2, Math.min(...ys) - 2,
        Math.max(...ys) + 2];
    }
    byId("site-floor").setAttribute("viewBox", `${x0} ${y0} ${x1 - x0} ${y1 - y0}`);
  }
}

new Room().start();
