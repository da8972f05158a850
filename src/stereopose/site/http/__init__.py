"""The site service's HTTP layer: the app, its API, logins and sessions, the server."""
