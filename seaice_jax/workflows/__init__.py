"""End-to-end jobs behind the ``seaice`` commands: each computes a typed result first, then writes its files
(radar block, satellite image sequence, demo)."""
