"""``python -m vpr_edge``: the ``vpr-edge`` command line."""
from vpr_edge.cli import main

if __name__ == "__main__":
    main()
