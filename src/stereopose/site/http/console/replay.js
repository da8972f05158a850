// The 3D replay of a past time window (a ticket, one of its steps, or a History search) from
// the stored poses (GET /api/poses): the skeletons frame by frame with the zones as prisms,
// the step's zones drawn thick, a slider to scrub and a play button. Shown in its own dialog.

import { poses } from "./api.js";
import { idColour } from "./colours.js";
import { byId } from "./dom.js";
import { dateTime } from "./feed.js";
import { headsTrace, loadPlotly, prism, sceneLayout, skeletonTrace } from "./view3d.js";

const MAX_FRAMES = 900;
const PLAY_MS = 100; // a drawn frame at most every 0.1 s

export class Replay {
  constructor() {
    this.dialog = byId("replay");
    this.root = byId("replay-view");
    this.title = byId("replay-title");
    this.info = byId("replay-info");
    this.slider = byId("replay-slider");
    this.playButton = byId("replay-play");
    this.frames = [];
    this.zones = [];
    this.highlight = new Set();
    this.index = 0;
    this.timer = null;
    this.asked = 0;
    this.drawing = false;
    this.pending = false;
    this.slider.addEventListener("input", () => this.go(Number(this.slider.value)));
    this.playButton.addEventListener("click", () => (this.timer ? this.pause() : this.play()));
    byId("replay-close").addEventListener("click", () => this.close());
    this.dialog.addEventListener("close", () => this.pause());
  }

  setZones(zones) { this.zones = zones; }

  /** Replay [since, until] (Unix seconds); `highlight`: zone names drawn thick. */
  async open({ since, until, title, highlight = [] }) {
    this.pause();
    this.frames = [];
    this.highlight = new Set(highlight);
    this.title.textContent = title;
    this.info.textContent = "loading";
    this.slider.max = "0";
    this.slider.value = "0";
    this.slider.disabled = true;
    this.root.dataset.frames = "0";
    if (!this.dialog.open) this.dialog.showModal();
    const asked = ++this.asked;
    let answer;
    try {
      [answer] = await Promise.all([
        poses({ since: since.toFixed(3), until: until.toFixed(3), max_frames: MAX_FRAMES }),
        loadPlotly(),
      ]);
    } catch (error) {
      if (asked === this.asked) this.info.textContent = `not loaded: ${error.detail || error.message}`;
      return;
    }
    if (asked !== this.asked) return;
    this.frames = answer.frames || [];
    this.root.dataset.frames = String(this.frames.length);
    if (!this.frames.length) {
      this.info.textContent = `no 3D poses stored from ${dateTime(since)} to ${dateTime(until)}`;
      window.Plotly.purge(this.root);
      return;
    }
    this.slider.max = String(this.frames.length - 1);
    this.slider.disabled = false;
    // open on the first frame with somebody in it
    this.go(Math.max(0, this.frames.findIndex((f) => (f.people || []).length)));
  }

  close() {
    this.pause();
    this.asked++;
    if (this.dialog.open) this.dialog.close();
  }

  play() {
    if (!this.frames.length) return;
    if (this.index >= this.frames.length - 1) this.go(0);
    this.playButton.textContent = "Pause";
    this.playButton.setAttribute("aria-pressed", "true");
    let last = performance.now();
    this.timer = setInterval(() => {
      // at the recording's own pace: as many frames on as its times say
      const now = performance.now();
      const target = this.frames[this.index].wall_t + (now - last) / 1000;
      last = now;
      let i = this.index;
      while (i < this.frames.length - 1 && this.frames[i + 1].wall_t <= target) i++;
      if (i === this.index && i < this.frames.length - 1) i++;
      this.go(i);
      if (i >= this.frames.length - 1) this.pause();
    }, PLAY_MS);
  }

  pause() {
    clearInterval(this.timer);
    this.timer = null;
    this.playButton.textContent = "Play";
    this.playButton.setAttribute("aria-pressed", "false");
  }

  go(index) {
    this.index = Math.max(0, Math.min(index, this.frames.length - 1));
    this.slider.value = String(this.index);
    this.root.dataset.index = String(this.index);
    const frame = this.frames[this.index];
    if (!frame) return;
    const people = frame.people || [];
    this.info.textContent = `${dateTime(frame.wall_t)} · frame ${this.index + 1} of ${this.frames.length} · ${people.length} people`;
    this.draw(frame);
  }

  async draw(frame) {
    if (this.drawing) {
      this.pending = true; // the newest frame is drawn when this one is
      return;
    }
    this.drawing = true;
    const people = frame.people || [];
    const traces = [
      ...this.zones.map((z) => prism({ ...z, state: "free" }, this.highlight.has(z.name))),
      ...people.map((p) => skeletonTrace(p, idColour(p.id))),
      headsTrace(people, (p) => idColour(p.id)),
    ];
    const layout = sceneLayout();
    try {
      await window.Plotly.react(this.root, traces, layout, { displayModeBar: false, responsive: true });
      this.root.dataset.drawn = String(this.index);
    } finally {
      this.drawing = false;
    }
    if (this.pending) {
      this.pending = false;
      this.draw(this.frames[this.index]);
    }
  }
}
