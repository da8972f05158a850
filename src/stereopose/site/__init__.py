"""The always-on service: HTTP app, health and metrics, storage retention."""
