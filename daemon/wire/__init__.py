"""What crosses a process boundary: the protocol envelope, rings, keys, argument checks, row codecs."""
