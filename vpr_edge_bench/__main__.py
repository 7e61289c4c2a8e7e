"""``python -m vpr_edge_bench [NAME [OPTIONS]]``: the experiments' runner (``runner.main``)."""
from vpr_edge_bench.runner import main

raise SystemExit(main())
