// The login both consoles share (the site's operator console and the control room's): the
// form, a session found again when the page loads, a session that ended, and a logout. The
// console itself comes in through three hooks: `enter(user)` shows it for the user logged in,
// `leave()` stops everything it asks the API (nothing more is asked with a gone session), and
// `settle()` lets what is in flight land before a logout ends the session.

import * as api from "./api.js";
import { byId } from "./dom.js";

export const ENDED = "Your session has ended: log in again.";

export class Login {
  constructor({ enter, leave, settle = async () => {}, beforeSubmit = () => {} }) {
    this.hooks = { enter, leave, settle, beforeSubmit };
    api.whenUnauthorized(() => this.show(ENDED));
    byId("login-form").addEventListener("submit", (e) => this.submit(e));
    byId("logout").addEventListener("click", () => this.logout());
  }

  /** At the page's load: the session the cookie holds, or the form. */
  async start() {
    if (!api.hasSessionCookie()) {
      this.show();
      return;
    }
    try {
      this.entered(await api.me());
    } catch {
      this.show();
    }
  }

  /** The form, with `message` above it; the console left. */
  show(message = "") {
    this.hooks.leave();
    byId("console").hidden = true;
    byId("login").hidden = false;
    byId("login-error").textContent = message;
    byId("login-password").value = "";
    byId(byId("login-user").value ? "login-password" : "login-user").focus();
  }

  async submit(event) {
    event.preventDefault();
    this.hooks.beforeSubmit();
    const button = byId("login-submit");
    button.disabled = true;
    byId("login-error").textContent = "";
    try {
      this.entered(await api.login(byId("login-user").value.trim(), byId("login-password").value));
    } catch (error) {
      const status = error instanceof api.ApiError ? error.status : 0;
      byId("login-error").textContent = status === 401 ? "Wrong user name or password."
        : status === 429 ? "Too many attempts: wait a moment and try again."
        : `Login failed: ${error.detail || error.message}`;
    } finally {
      button.disabled = false;
      byId("login-password").value = "";
    }
  }

  async logout() {
    await this.hooks.settle();
    try {
      await api.logout();
    } catch {
      // the session is gone either way
    }
    this.show("Logged out.");
  }

  entered(user) {
    byId("user").textContent = `${user.username} (${user.role})`;
    document.body.dataset.role = user.role;
    byId("login").hidden = true;
    byId("console").hidden = false;
    this.hooks.enter(user);
  }
}
