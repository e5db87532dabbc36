"""Wire codecs: core state to protocol messages, as bytes (no transport here)."""
