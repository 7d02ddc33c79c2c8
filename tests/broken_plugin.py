"""A controller plugin whose module cannot even be imported (tests/test_hot_swap.py): the daemon
refuses it, says so, and starts."""
raise RuntimeError("this plugin's module fails as it is imported")
