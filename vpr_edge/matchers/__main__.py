"""``python -m vpr_edge.matchers``: the parameter table of docs/matchers.md."""
from vpr_edge.matchers.registry import params_table

print(params_table())
