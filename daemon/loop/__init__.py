"""The 1 ms loop process: the cycle, its command port and handlers, safety, lease, tracking, shadow, stats."""
