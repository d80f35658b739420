"""The Zenoh protocol (key expressions, payloads) shared by the daemon and the watcher."""
