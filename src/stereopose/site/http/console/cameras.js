// The camera strip: per camera its live picture (the newest snapshot with skeletons and ids,
// fetched a few times a second while the page is visible and the camera up) and its health,
// with a clear DOWN badge. A click on a picture opens it large (the camera of a new alarm is
// opened so by the console); the large view follows the same pictures and closes with its
// button or Escape. The Regions toggle draws over each picture where detection looked in the
// camera's last step (tracked people, its own people, motion, a scan), refreshed with its health.
// Under a camera knocked out of place, the calibration keeper's word: being placed again, a new
// pose proposed (with Accept for an admin), accepted, or not corrected and why.

import { text } from "./dom.js";

const PERIOD_MS = 500; // 2 pictures a second per camera

/** A camera's picture URL, its name one escaped path segment (a name may hold ? # / % <). */
export const snapshotUrl = (name) => `/api/cameras/${encodeURIComponent(name)}/snapshot.jpg`;

export class CameraStrip {
  constructor(root, large = null) {
    this.root = root;
    this.cards = new Map(); // name -> {card, img, badge, stats, health, url, loading}
    this.timer = null;
    this.active = true; // the live tab is shown
    this.large = large; // {dialog, img, title, why, close} or null
    this.opened = null; // the camera shown large
    this.onAccept = null; // (camera) => accept the pose proposed for it
    document.addEventListener("visibilitychange", () => this.schedule());
    if (large) {
      large.close.addEventListener("click", () => this.closeLarge());
      large.dialog.addEventListener("keydown", (e) => {
        if (e.key === "Escape") this.closeLarge();
      });
      document.addEventListener("keydown", (e) => {
        if (e.key === "Escape" && this.opened) this.closeLarge();
      });
    }
  }

  /** The camera `name` shown large (why: a line saying why it opened, e.g. the alarm's;
   * incident: the incident it was opened for, if any). */
  open(name, why = "", incident = null) {
    const c = this.cards.get(name);
    if (!this.large || !c) return;
    this.opened = name;
    const { dialog, img, title } = this.large;
    dialog.dataset.camera = name;
    if (incident === null) delete dialog.dataset.incident;
    else dialog.dataset.incident = String(incident);
    title.textContent = name;
    this.large.why.textContent = why;
    img.setAttribute("aria-label", `${name} live picture, large`);
    this.paint(c.img);
    for (const card of this.cards.values()) card.card.classList.toggle("opened", card === c);
    if (!dialog.open) dialog.show(); // not modal: the feed and its Ack stay usable
  }

  /** The large view's canvas painted with a decoded picture (no second request for it). */
  paint(picture) {
    const canvas = this.large && this.large.img;
    if (!canvas || !picture.naturalWidth) return;
    if (canvas.width !== picture.naturalWidth || canvas.height !== picture.naturalHeight) {
      canvas.width = picture.naturalWidth;
      canvas.height = picture.naturalHeight;
    }
    canvas.getContext("2d").drawImage(picture, 0, 0);
    canvas.dataset.painted = String(Number(canvas.dataset.painted || 0) + 1);
  }

  closeLarge() {
    if (!this.large) return;
    this.opened = null;
    this.large.dialog.close();
    delete this.large.dialog.dataset.camera;
    delete this.large.dialog.dataset.incident;
    for (const card of this.cards.values()) card.card.classList.remove("opened");
  }

  setCameras(cameras) {
    this.root.replaceChildren();
    this.cards.clear();
    for (const cam of cameras) {
      const card = document.createElement("figure");
      card.className = "camera-card";
      card.dataset.camera = cam.name;
      const frame = document.createElement("div");
      frame.className = "snapshot";
      if (Array.isArray(cam.image_size) && cam.image_size[0] > 0 && cam.image_size[1] > 0) {
        frame.style.aspectRatio = `${cam.image_size[0]} / ${cam.image_size[1]}`; // CSSOM: no inline style
      }
      const img = document.createElement("img");
      img.alt = `${cam.name} live picture`;
      img.dataset.camera = cam.name;
      const down = text("div", "NO PICTURE", "down-overlay");
      const regions = document.createElement("div");
      regions.className = "regions";
      regions.setAttribute("aria-hidden", "true");
      frame.append(img, regions, down);
      const caption = document.createElement("figcaption");
      const name = text("span", cam.name, "camera-name");
      const badge = text("span", "", "badge");
      const stats = text("span", "", "camera-stats muted");
      const light = text("span", "", "camera-light");
      light.hidden = true;
      const calib = text("span", "", "camera-calibration");
      calib.hidden = true;
      caption.append(name, badge, light, stats, calib);
      card.append(frame, caption);
      frame.title = `${cam.name}: click to enlarge`;
      frame.addEventListener("click", () => this.open(cam.name));
      this.root.appendChild(card);
      this.cards.set(cam.name, { card, img, badge, light, stats, calib, regions, health: null,
        url: snapshotUrl(cam.name), loading: false });
      this.setHealth(cam.name, cam.health);
      this.setLight(cam.name, cam.light);
      this.setRegions(cam.name, cam.regions);
    }
    // the cards drawn again keep the keeper's last word on each camera until its next poll
    if (this.lastCalibration) this.setCalibration(...this.lastCalibration);
    this.schedule();
  }

  setHealth(name, health) {
    const c = this.cards.get(name);
    if (!c || !health) return;
    c.health = health;
    const down = health.state === "down";
    c.card.classList.toggle("down", down);
    c.card.dataset.state = health.state;
    c.badge.textContent = down ? "DOWN" : "UP";
    c.badge.className = `badge ${down ? "badge-down" : "badge-up"}`;
    const age = typeof health.last_frame_age_s === "number" ? `${health.last_frame_age_s.toFixed(1)} s` : "-";
    const fps = typeof health.fps === "number" ? health.fps.toFixed(1) : "-";
    c.stats.textContent = `${fps} fps · last frame ${age} · ${health.reconnects ?? 0} reconnects` +
      (health.dropped_frames ? ` · ${health.dropped_frames} dropped` : "");
  }

  /** The camera's light ({mode, brightness, noise}; absent: not watched): said on its card
   * unless it is day. */
  setLight(name, light) {
    const c = this.cards.get(name);
    if (!c) return;
    const mode = light && typeof light.mode === "string" ? light.mode : "day";
    const said = {
      night: "NIGHT",
      black: "SEES BLACK",
      blinded: "BLINDED",
    }[mode];
    c.card.dataset.light = mode;
    c.light.textContent = said || "";
    c.light.hidden = !said;
    c.light.className = `camera-light light-${mode}`;
    const brightness = light && typeof light.brightness === "number" ? light.brightness.toFixed(0) : "-";
    const noise = light && typeof light.noise === "number" ? light.noise.toFixed(1) : "-";
    c.light.title = mode === "night"
      ? `dark or noisy (brightness ${brightness}, noise ${noise}): pictures prepared for the detector`
      : `brightness ${brightness}, noise ${noise}: people may be missed`;
  }

  /** The keeper's figures (GET /api/calibration; null: not running) on each camera's card;
   * role: the user's (only an admin gets Accept). */
  setCalibration(body, role) {
    this.lastCalibration = [body, role];
    const cases = (body && body.cameras) || {};
    const proposals = (body && body.proposals) || {};
    const corrected = (body && body.corrected) || {};
    for (const [name, c] of this.cards) {
      const state = cases[name];
      const proposal = proposals[name];
      const parts = [];
      let kind = "";
      if (proposal) {
        kind = proposal.accepted_by ? "accepted" : "proposed";
        parts.push(text("span", proposal.accepted_by
          ? `new pose accepted by ${proposal.accepted_by}: applied at the next step`
          : `new pose proposed: turned ${Number(proposal.turned_deg).toFixed(2)}°, moved `
            + `${Number(proposal.moved_m).toFixed(2)} m, ${Number(proposal.reprojection_px).toFixed(1)} px`));
        if (!proposal.accepted_by && role === "admin") {
          const button = text("button", "Accept", "accept-pose");
          button.type = "button";
          button.dataset.camera = name;
          button.title = `apply the proposed pose to ${name}`;
          button.addEventListener("click", () => {
            button.disabled = true;
            if (this.onAccept) this.onAccept(name);
          });
          parts.push(button);
        }
      } else if (state) {
        kind = state.reason ? "failing" : "placing";
        parts.push(text("span", state.reason
          ? `not corrected: ${state.reason} (tried ${state.tries})`
          : `calibration drift: placing again (${state.samples} samples${state.working ? ", working" : ""})`));
      } else if (corrected[name]) {
        kind = "corrected";
        parts.push(text("span", `corrected ${corrected[name]}× while serving`));
      }
      c.calib.replaceChildren(...parts);
      c.calib.hidden = parts.length === 0;
      c.calib.dataset.state = kind;
    }
  }

  /** Accepting a pose failed: said under the camera. */
  setCalibrationError(name, message) {
    const c = this.cards.get(name);
    if (!c) return;
    c.calib.replaceChildren(text("span", `not accepted: ${message}`, "error"));
    c.calib.hidden = false;
  }

  /** Where detection looked in the camera's last step: {mode, regions: [[x, y, w, h, why]]}
   * as fractions of the picture (null: whole frames, or not known yet). */
  setRegions(name, view) {
    const c = this.cards.get(name);
    if (!c) return;
    const boxes = view && Array.isArray(view.regions) ? view.regions : [];
    c.card.dataset.detection = view && typeof view.mode === "string" ? view.mode : "";
    c.regions.replaceChildren(...boxes.filter((b) => Array.isArray(b) && b.length >= 4).map((b) => {
      const box = document.createElement("div");
      const why = String(b[4] || "");
      box.className = `region ${why.split("+").map((w) => `why-${w.replace(/[^a-z]/g, "")}`).join(" ")}`;
      box.title = why;
      const pct = (v) => `${Math.max(0, Math.min(100, 100 * Number(v) || 0)).toFixed(2)}%`;
      box.style.left = pct(b[0]);
      box.style.top = pct(b[1]);
      box.style.width = pct(b[2]);
      box.style.height = pct(b[3]);
      return box;
    }));
  }

  /** The Regions toggle: draw the regions over every picture, or not. */
  showRegions(on) {
    this.root.classList.toggle("show-regions", Boolean(on));
  }

  show(active) {
    this.active = active;
    this.schedule();
  }

  schedule() {
    const run = this.active && document.visibilityState === "visible";
    if (run && !this.timer) {
      this.timer = setInterval(() => this.refresh(), PERIOD_MS);
      this.refresh();
    } else if (!run && this.timer) {
      clearInterval(this.timer);
      this.timer = null;
    }
  }

  /** Resolves once no picture is being fetched (or after `timeoutMs`). */
  async idle(timeoutMs = 3000) {
    const until = performance.now() + timeoutMs;
    while ([...this.cards.values()].some((c) => c.loading) && performance.now() < until) {
      await new Promise((resolve) => setTimeout(resolve, 50));
    }
  }

  refresh() {
    for (const c of this.cards.values()) {
      // a camera down or without a first frame has no new picture (the server says 503)
      if (c.loading || !c.url || !c.health || c.health.state !== "up" || c.health.frames === 0) continue;
      c.loading = true;
      const next = new Image();
      next.alt = c.img.alt;
      next.dataset.camera = c.img.dataset.camera;
      next.src = `${c.url}?t=${Date.now()}`;
      // decoded off the main thread before it is shown, so a picture never holds up an alarm
      next.decode().then(
        () => {
          c.img.replaceWith(next);
          c.img = next;
          c.loading = false;
          if (this.opened === next.dataset.camera) this.paint(next);
        },
        () => {
          c.loading = false;
        },
      );
    }
  }
}
