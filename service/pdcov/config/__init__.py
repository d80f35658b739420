"""The mission config (docs/mission-config.md), one module per section: ``load`` reads a
file into a ``mission.Mission``; ``keys`` is the schema of every section; ``values`` the
checks they share. Above the core, below every command."""
