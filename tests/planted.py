"""A module a hostile request might name (tests/test_hot_swap.py): the test asks the planner
worker whether it was ever imported there."""
