"""The operator's live view of a run: HTTP server, state and the run attachment."""
