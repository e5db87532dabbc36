"""``fleet-view``: the fleet live in a browser, and PNG snapshots of it.

``state`` keeps what the viewer knows (fed by zenoh callbacks) and builds the frames pages
receive; ``app`` serves the page and its websocket; ``snapshot`` renders a PNG with Pillow.
"""
