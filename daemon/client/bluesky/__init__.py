"""pneumad for Bluesky (``pip install -e '.[bluesky]'``): a rig as an ophyd-async device, its
daemon-side 1 kHz recordings as HDF5 stream resources, and the rig's experiments as plans
(docs/bluesky.md). Client side only: it talks to daemons over the documented protocol."""
