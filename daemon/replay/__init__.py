"""``pneumactl replay``: a recorded run again on the rig's model (docs/model.md), in a process of
its own that pneumactl starts (the client never imports the loop's side)."""
