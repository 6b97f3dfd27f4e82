"""Mission simulator: drive a route under a truth model, write a recording."""
