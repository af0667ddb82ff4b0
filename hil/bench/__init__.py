"""The bench: its file, its secured zenoh (certificates), the long-running rig service."""
