"""The experiments ``python -m vpr_edge_bench NAME`` runs, one module each (``runner``): each module's docstring
says what it measures (first line) and how, its ``main(argv) -> int`` runs it."""
