"""Log providers: where the frames a session serves come from."""
