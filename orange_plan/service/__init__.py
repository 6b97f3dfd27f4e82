"""The mid-mission replanning HTTP service (``orange-plan serve``): API, store, operator page.

``create_app`` builds the FastAPI application; ``missions`` keeps one ``MissionSession`` per
mission and rebuilds it from the SQLite ``store`` after a restart; ``static/`` holds the
operator page (plain SVG and a small hand-written script, no external assets).
"""
