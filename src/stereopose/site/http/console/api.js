// The console's calls to the stereopose HTTP API: JSON over fetch with the session cookie,
// the CSRF header on every state-changing request, and the live channel (Server-Sent Events).

export class ApiError extends Error {
  constructor(status, detail) {
    super(`${status}: ${detail}`);
    this.status = status;
    this.detail = detail;
  }
}

let csrfToken = null;
let onUnauthorized = () => {};

/** What to do when the server says the session is gone (401): show the login again. */
export function whenUnauthorized(callback) {
  onUnauthorized = callback;
}

function cookie(name) {
  for (const part of document.cookie.split(";")) {
    const [key, ...rest] = part.trim().split("=");
    if (key === name) return decodeURIComponent(rest.join("="));
  }
  return null;
}

/** The CSRF value of this session: the login's answer, else the readable cookie. */
export function csrf() {
  return csrfToken || cookie("stereopose_csrf");
}

/** Whether the browser holds a session's readable cookie (then /api/me is worth asking). */
export function hasSessionCookie() {
  return cookie("stereopose_csrf") !== null;
}

async function detailOf(response) {
  try {
    const body = await response.json();
    return typeof body.detail === "string" ? body.detail : JSON.stringify(body.detail);
  } catch {
    return response.statusText || "no answer";
  }
}

/** `method` `path` with an optional JSON body (or `text` of the media `type`); the parsed JSON
 * answer (null for 204). */
export async function call(path, { method = "GET", body, text, type } = {}) {
  const headers = { Accept: "application/json" };
  if (method !== "GET" && method !== "HEAD") headers["X-CSRF-Token"] = csrf() || "";
  if (body !== undefined) headers["Content-Type"] = "application/json";
  if (text !== undefined) headers["Content-Type"] = type;
  const response = await fetch(path, {
    method,
    headers,
    body: text !== undefined ? text : body === undefined ? undefined : JSON.stringify(body),
    credentials: "same-origin",
    cache: "no-store",
  });
  if (response.status === 401 && path !== "/api/login") {
    onUnauthorized();
  }
  if (!response.ok) throw new ApiError(response.status, await detailOf(response));
  if (response.status === 204) return null;
  return response.json();
}

export async function login(username, password) {
  const answer = await call("/api/login", { method: "POST", body: { username, password } });
  csrfToken = answer.csrf;
  return answer;
}

export async function logout() {
  try {
    await call("/api/logout", { method: "POST" });
  } finally {
    csrfToken = null;
  }
}

export const me = () => call("/api/me");
export const cameras = () => call("/api/cameras");
export const zones = () => call("/api/zones");
export const people = () => call("/api/people");
export const ack = (id) => call(`/api/events/${encodeURIComponent(id)}/ack`, { method: "POST" });
export const ackIncident = (id) => call(`/api/incidents/${encodeURIComponent(id)}/ack`, { method: "POST" });
export const shelveIncident = (id, reason, durationS) => call(
  `/api/incidents/${encodeURIComponent(id)}/shelve`,
  { method: "POST", body: { reason, duration_s: durationS } },
);
export const alarmRates = () => call("/api/alarm-rates");
export const warnings = () => call("/api/warnings");
export const silenceOutput = (name, minutes, reason) => call(
  `/api/warnings/${encodeURIComponent(name)}/silence`, { method: "POST", body: { minutes, reason } },
);
export const unsilenceOutput = (name) => call(
  `/api/warnings/${encodeURIComponent(name)}/silence`, { method: "DELETE" },
);
export const testOutput = (name) => call(
  `/api/warnings/${encodeURIComponent(name)}/test`, { method: "POST" },
);
export const calibration = () => call("/api/calibration");
export const acceptPose = (camera) => call(
  `/api/calibration/${encodeURIComponent(camera)}/accept`, { method: "POST" },
);

/** The query string of history filters: only the ones given. */
export function query(filters) {
  const params = new URLSearchParams();
  for (const [key, value] of Object.entries(filters)) {
    if (value !== null && value !== undefined && value !== "") params.set(key, String(value));
  }
  const text = params.toString();
  return text ? `?${text}` : "";
}

export const events = (filters = {}) => call(`/api/events${query(filters)}`);
export const incidents = (filters = {}) => call(`/api/incidents${query(filters)}`);
export const poses = (filters) => call(`/api/poses${query(filters)}`);
export const tickets = () => call("/api/tickets");
export const ticket = (id) => call(`/api/tickets/${encodeURIComponent(id)}`);
export const addTicket = (toml) => call("/api/tickets", { method: "POST", text: toml, type: "application/toml" });
export const ticketAct = (id, act, body) => call(
  `/api/tickets/${encodeURIComponent(id)}/${act}`, { method: "POST", body },
);
export const ticketReportUrl = (id) => `/api/tickets/${encodeURIComponent(id)}/report`;
export const eventsCsvUrl = (filters = {}) => `/api/events.csv${query(filters)}`;

/**
 * The live channel: `handlers` maps event names (people, event, incident, zones, cameras, ack,
 * closed) to functions of the parsed data; `onState(connected)` hears the link go up and down.
 * A channel the server closed (a 401, a restart) is opened again after checking the session;
 * one it ended for another of the user's streams (`closed`) is not opened again by itself.
 */
export class Live {
  constructor(handlers, onState) {
    this.handlers = handlers;
    this.onState = onState;
    this.source = null;
    this.retry = null;
    this.stopped = false;
  }

  start() {
    this.stopped = false;
    this.open();
  }

  open() {
    if (this.stopped) return;
    const source = new EventSource("/api/live");
    this.source = source;
    source.addEventListener("open", () => this.onState(true));
    for (const [name, handler] of Object.entries(this.handlers)) {
      source.addEventListener(name, (message) => {
        let data;
        try {
          data = JSON.parse(message.data);
        } catch {
          return; // a damaged message: the next one replaces it
        }
        handler(data);
      });
    }
    source.addEventListener("error", () => {
      this.onState(false);
      if (source.readyState !== EventSource.CLOSED || this.stopped) return; // it retries itself
      source.close();
      clearTimeout(this.retry);
      this.retry = setTimeout(async () => {
        try {
          await me(); // a 401 here shows the login and stops the channel
          this.open();
        } catch (error) {
          if (!(error instanceof ApiError && error.status === 401)) this.open();
        }
      }, 2000);
    });
  }

  stop() {
    this.stopped = true;
    clearTimeout(this.retry);
    if (this.source) this.source.close();
    this.source = null;
  }
}
