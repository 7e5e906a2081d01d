"""xviz-server: an asyncio WebSocket server for the XVIZ v2 protocol."""

__version__ = "0.1.0"
