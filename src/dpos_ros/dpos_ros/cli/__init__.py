"""Command-line tools of dpos (console scripts installed into the venv)."""
