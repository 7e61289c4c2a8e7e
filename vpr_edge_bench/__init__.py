"""The lab beside the runtime: what measures vpr-edge, not what runs on a vehicle. Not in the wheel (pyproject's
package list leaves it out); run from a checkout, at its root, with vpr-edge installed (``pip install -e .``).

* ``python -m vpr_edge_bench`` lists the experiments, ``python -m vpr_edge_bench NAME --help`` tells one's
  options (``runner``; each experiment a module of ``experiments``);
* ``streams``: test streams derived from a frame-aligned reference/query pair (speeds, stops, a detour), and
  ``folder.StreamsFolder``: a folder of them, checked and evaluated stream by stream;
* ``synthetic``: a route of global descriptors at any scale and a hard stream over it;
* ``yardstick``: the speed every timing is read against;
* ``doc_tables``: the README's and docs/results.md's tables, from the figures the ``results`` experiment wrote.

The runtime (``vpr_edge``) never imports this package.
"""
