"""The web map's two access levels for the operator tests: a view token, an operator token, both."""

from __future__ import annotations

from pdcov.ground.web_auth import WebAccess, served_names

VIEW = "view-Token_of.the~map-0123456789"
OPERATOR = "operator-Token_of.the~map-9876543210"
NAMES = served_names("127.0.0.1", "groundstation")
BOTH = WebAccess(VIEW, NAMES, OPERATOR)
VIEW_ONLY = WebAccess(VIEW, NAMES)
