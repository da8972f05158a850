// History: events filtered by time range, person, zone and type (/api/events), a table with
// each alarm's clips playable in the page, and the CSV export of the same filters. While the
// tab is shown, the rows of recent alarms are asked for again every few seconds: a clip is
// finished seconds after its alarm (clip_post_s later, its full stream's copy just after), and
// its play button comes into the row as soon as the server lists it, without a new search.

import { ApiError, events, eventsCsvUrl } from "./api.js";
import { byId } from "./dom.js";
import { ackText, dateTime, describe, typeText } from "./feed.js";

const PAGE = 200;
const CLIP_POLL_MS = 2000;
// an alarm's clips may still come this long after it: clip_post_s (at most 600 s), the
// writing, and the full stream's copy after the drawn clip
const CLIP_PENDING_S = 660;
const CLIP_PAGES = 5; // pages of events asked at one look, at most
const TYPES = ["enter", "exit", "approach", "dwell", "left_work_area", "person_down", "fall",
  "lone_worker", "work_position", "immobile", "overreach", "camera_down", "camera_up",
  "camera_moved", "calibration_drift"];


function epoch(input) {
  if (!input.value) return "";
  const ms = new Date(input.value).getTime(); // the browser's local time
  return Number.isFinite(ms) ? (ms / 1000).toFixed(3) : "";
}

function cell(row, content, className = "") {
  const td = document.createElement("td");
  if (className) td.className = className;
  if (content instanceof Node) td.appendChild(content);
  else td.textContent = content;
  row.appendChild(td);
  return td;
}

/** A clip's button: its camera, and "full" for the full stream's copy beside the drawn clip
 * (clip names end in _<camera>.mp4 or _<camera>.full.mp4). */
function clipLabel(url) {
  const name = clipFile(url);
  const full = name.endsWith(".full.mp4");
  const stem = name.replace(/(\.full)?\.mp4$/, "");
  const camera = stem.includes("_") ? stem.slice(stem.lastIndexOf("_") + 1) : stem;
  return full ? `${camera} full` : camera;
}

/** The file name of a clip's URL as the server gives it (/api/clips/<file>, maybe escaped). */
function clipFile(url) {
  const file = String(url).split("/").pop() || "";
  try {
    return decodeURIComponent(file);
  } catch {
    return file; // a bare %: not escaped
  }
}

/** A clip's URL with its file name escaped as one path segment. */
const clipUrl = (url) => `/api/clips/${encodeURIComponent(clipFile(url))}`;

/** What of an event's row can change after it is drawn: its clips and acknowledgement. */
const rowState = (e) => JSON.stringify([e.clips || [], e.ack || null]);

export class History {
  constructor(replay) {
    this.replay = replay;
    this.form = byId("history-form");
    this.rows = byId("h-rows");
    this.more = byId("h-more");
    this.csv = byId("h-csv");
    this.info = byId("h-info");
    this.player = byId("player");
    this.playerInfo = byId("player-info");
    this.download = byId("player-download");
    this.playerError = byId("player-error");
    // drawn clips are MPEG-4 Part 2, which browsers' video elements do not decode: the
    // server plays them as Motion JPEG into an <img> (GET /api/clips/<file>/play)
    this.frames = byId("player-frames");
    this.frames.addEventListener("error", () => {
      this.playerError.textContent = "The clip cannot be played here; download it instead.";
      this.playerError.hidden = false;
    });
    this.player.addEventListener("error", () => {
      if (this.player.hidden || !this.player.getAttribute("src")) return;
      this.showFrames(this.player.getAttribute("src")); // a format this browser does not decode
    });
    this.player.addEventListener("loadeddata", () => {
      this.playerError.hidden = true;
    });
    this.zoneSelect = byId("h-zone");
    this.typeSelect = byId("h-type");
    this.oldest = null;
    this.asked = 0; // the newest search: an older one's late answer is dropped
    this.visible = false;
    this.clipTimer = null;
    for (const t of TYPES) this.typeSelect.appendChild(new Option(typeText(t), t));
    this.form.addEventListener("submit", (e) => {
      e.preventDefault();
      this.search();
    });
    this.form.addEventListener("input", () => this.updateCsv());
    this.more.addEventListener("click", () => this.search(true));
    byId("h-replay").addEventListener("click", () => this.replayWindow());
    this.updateCsv();
  }

  /** The tab shown or hidden: recent alarms' clips asked for while it is shown. */
  show(visible) {
    this.visible = visible;
    this.watchClips();
  }

  /** The ids of the shown alarms whose clips may still come, oldest first. */
  pendingIds() {
    const now = Date.now() / 1000;
    const ids = [];
    for (const tr of this.rows.children) {
      const t = Number(tr.dataset.wallT);
      if (tr.dataset.level !== "alarm" || !Number.isFinite(t) || now - t > CLIP_PENDING_S) continue;
      ids.push(Number(tr.dataset.eventId));
    }
    return ids.filter(Number.isFinite).sort((a, b) => a - b);
  }

  /** The next look at the recent alarms' clips, while the tab is shown and one may come. */
  watchClips() {
    clearTimeout(this.clipTimer);
    this.clipTimer = null;
    if (this.visible && this.pendingIds().length) {
      this.clipTimer = setTimeout(() => this.refreshClips(), CLIP_POLL_MS);
    }
  }

  /** The shown rows from the oldest pending alarm on asked again by id with the same filters
   * (pages of the events after it, oldest first, up to the newest pending one: on a busy site
   * more than a page of events may have come since); each row whose clips (or
   * acknowledgement) changed is drawn again in place. */
  async refreshClips() {
    this.clipTimer = null;
    const ids = this.pendingIds();
    if (!this.visible || !ids.length) return;
    const asked = this.asked;
    const f = this.filters();
    let after = ids[0] - 1;
    const last = ids[ids.length - 1];
    for (let page = 0; page < CLIP_PAGES && after < last; page += 1) {
      let answer = null;
      try {
        answer = await events({ ...f, after_id: after, limit: PAGE });
      } catch {
        break; // asked again at the next look
      }
      // hidden meanwhile, or a new search drew the table (and looks on itself)
      if (!this.visible || asked !== this.asked) return;
      const got = (answer && answer.events) || [];
      for (const e of got) {
        const tr = this.rows.querySelector(`tr[data-event-id="${Number(e.id)}"]`);
        if (tr && tr.dataset.state !== rowState(e)) tr.replaceWith(this.row(e));
      }
      if (got.length < PAGE) break;
      after = Math.max(...got.map((e) => Number(e.id)));
    }
    this.watchClips();
  }

  setZones(zones) {
    const current = this.zoneSelect.value;
    const names = zones.map((z) => z.name);
    const have = [...this.zoneSelect.options].map((o) => o.value).filter(Boolean);
    if (names.join("\n") === have.join("\n")) return;
    this.zoneSelect.replaceChildren(new Option("any", ""));
    for (const name of names) this.zoneSelect.appendChild(new Option(name, name));
    this.zoneSelect.value = names.includes(current) ? current : "";
  }

  filters() {
    return {
      since: epoch(byId("h-since")),
      until: epoch(byId("h-until")),
      person: byId("h-person").value.trim(),
      zone: this.zoneSelect.value,
      type: this.typeSelect.value,
    };
  }

  /** The 3D replay of the From..To window (an open end: the last 10 minutes up to To, or
   * from From). */
  replayWindow() {
    const f = this.filters();
    const now = Date.now() / 1000;
    let until = f.until ? Number(f.until) : now;
    let since = f.since ? Number(f.since) : until - 600;
    if (f.since && !f.until) until = Math.min(now, since + 600);
    if (until <= since) {
      this.info.textContent = "the replay's To must be after its From";
      return;
    }
    since = Math.max(since, until - 3 * 3600);
    this.replay.open({ since, until, title: "History in 3D" });
  }

  updateCsv() {
    this.csv.href = eventsCsvUrl(this.filters());
  }

  async search(older = false) {
    const filters = { ...this.filters(), limit: PAGE };
    if (older && this.oldest !== null) filters.before_id = this.oldest;
    this.updateCsv();
    this.info.textContent = "searching";
    const asked = ++this.asked;
    let answer;
    try {
      answer = await events(filters);
    } catch (error) {
      if (asked !== this.asked || (error instanceof ApiError && error.status === 401)) return;
      this.info.textContent = `not searched: ${error.detail || error.message}`;
      return;
    }
    if (asked !== this.asked) return;
    const found = answer.events || [];
    if (!older) this.rows.replaceChildren();
    for (const e of found) this.rows.appendChild(this.row(e));
    if (found.length) this.oldest = found[found.length - 1].id;
    this.more.hidden = found.length < PAGE;
    const shown = this.rows.children.length;
    this.info.textContent = `${shown} event${shown === 1 ? "" : "s"}`;
    this.watchClips();
  }

  row(e) {
    const tr = document.createElement("tr");
    tr.dataset.eventId = String(e.id);
    tr.className = `level-${e.level || "info"}`;
    tr.dataset.type = e.type;
    tr.dataset.level = e.level || "info";
    tr.dataset.wallT = String(e.wall_t);
    tr.dataset.state = rowState(e);
    cell(tr, dateTime(e.wall_t), "time");
    cell(tr, e.level || "info", `level level-${e.level || "info"}`);
    cell(tr, typeText(e.type));
    cell(tr, e.zone || "");
    cell(tr, e.person !== null && e.person !== undefined && e.person >= 0 ? String(e.person) : "");
    // a zone's or a rule's event names no camera: the cameras its clips are of show it
    const seenBy = [...new Set((e.clips || []).map((c) => clipLabel(clipUrl(c)).replace(/ full$/, "")))];
    cell(tr, e.camera || seenBy.join(", "), e.camera ? "" : "muted");
    cell(tr, e.incident !== null && e.incident !== undefined
      ? `#${e.incident}${e.priority ? ` P${e.priority}` : ""}` : "", "incident");
    cell(tr, ackText(e.ack));
    const clips = document.createElement("span");
    for (const given of e.clips || []) {
      const url = clipUrl(given);
      const button = document.createElement("button");
      button.type = "button";
      button.className = "play";
      button.dataset.clip = url;
      button.textContent = clipLabel(url);
      button.title = `play ${clipFile(url)}`;
      button.addEventListener("click", () => this.play(url, e));
      clips.appendChild(button);
    }
    cell(tr, clips, "clips");
    tr.title = describe(e);
    return tr;
  }

  play(url, e) {
    this.playerError.hidden = true;
    this.download.href = url;
    this.download.hidden = false;
    this.playerInfo.textContent = `${dateTime(e.wall_t)} ${describe(e)}`;
    if (!url.endsWith(".full.mp4")) {
      this.showFrames(url); // a drawn clip
      return;
    }
    this.frames.hidden = true;
    this.frames.removeAttribute("src");
    this.player.hidden = false;
    this.player.src = url; // a full stream's copy (H.264): the video element plays it
    this.player.play().catch(() => {}); // a browser may refuse to start playing by itself
  }

  /** The clip at `url` played by the server as Motion JPEG frames into the <img>. */
  showFrames(url) {
    this.player.pause();
    this.player.removeAttribute("src");
    this.player.load();
    this.player.hidden = true;
    this.frames.hidden = false;
    this.frames.src = `${url}/play?at=${Date.now()}`; // a new request: played from the start
  }
}
