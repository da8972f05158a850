// The alarm sound, synthesised with the Web Audio API (no file): two short high tones every
// two seconds while an alarm is unacknowledged, unless muted. A browser lets audio start only
// after a user gesture, so the context is made on the first click or key press.

const PERIOD_MS = 2000;

export class Alarm {
  constructor() {
    this.context = null;
    this.muted = false;
    this.on = false;
    this.timer = null;
    this.onChange = null; // told when the sound can start
    this.unlockedAt = -Infinity;
  }

  unlock() {
    if (this.context || typeof AudioContext === "undefined") return;
    this.context = new AudioContext();
    this.unlockedAt = performance.now();
    if (this.on) this.beep();
    if (this.onChange) this.onChange();
  }

  /** Whether an alarm should sound but the browser has not let the sound start yet. */
  blocked() {
    return this.on && !this.muted && !this.context;
  }

  mute(muted) {
    this.muted = muted;
    document.body.dataset.sound = this.state();
  }

  sounding(on) {
    if (on === this.on) return;
    this.on = on;
    clearInterval(this.timer);
    this.timer = null;
    if (on) {
      this.beep();
      this.timer = setInterval(() => this.beep(), PERIOD_MS);
    }
    document.body.dataset.sound = this.state();
  }

  /** "off", "muted" or "sounding": what the operator hears. */
  state() {
    if (!this.on) return "off";
    return this.muted ? "muted" : "sounding";
  }

  beep() {
    const ctx = this.context;
    if (!ctx || this.muted) return;
    if (ctx.state === "suspended") ctx.resume();
    const now = ctx.currentTime;
    for (const [start, freq] of [[0, 880], [0.22, 660]]) {
      const osc = ctx.createOscillator();
      const gain = ctx.createGain();
      osc.type = "square";
      osc.frequency.value = freq;
      gain.gain.setValueAtTime(0.0001, now + start);
      gain.gain.exponentialRampToValueAtTime(0.15, now + start + 0.02);
      gain.gain.exponentialRampToValueAtTime(0.0001, now + start + 0.18);
      osc.connect(gain).connect(ctx.destination);
      osc.start(now + start);
      osc.stop(now + start + 0.2);
    }
  }
}
