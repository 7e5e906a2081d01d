"""Build XVIZ metadata and state updates from Python."""
