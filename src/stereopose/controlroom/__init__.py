"""One control room for many sites: every site's event log in over the central broker, each
(site, id) stored once, the sites' states, and an HTTP API with the site console's login
(`stereopose control-room CONFIG.toml`; docs/control-room.md)."""
