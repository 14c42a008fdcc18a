"""The trainer's dashboard: a viser app inside the web process, behind the server's login."""
