"""The Zenoh protocol of pdcov (docs/protocol.md), shared by the daemon and the watcher.

keys: key expressions under ``pdcov/<vehicle_id>/``. status, tiles, snapshot, footprint,
mission, frames: payload codecs with a schema version; every decoder validates what it is given and
raises ``BusPayloadError`` naming the key and the fault (a hostile or broken peer never
corrupts a grid). grid_state: the grid as a subscriber holds it. session: the Zenoh session
config from the mission YAML's ``bus`` section.
"""
