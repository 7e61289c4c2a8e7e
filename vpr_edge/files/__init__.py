"""Files, safely, one module per job (import from the module that holds the function):

* ``checks``: outputs checked before the work (writable, not special, not an input);
* ``temps``: temporary and lock file names beside an output, and what writers that died left;
* ``atomic``: atomic writing (a temporary file, then renamed) with the replaced file's mode;
* ``one_writer``: the one-writer lock of an output;
* ``npz``: ``.npz`` arrays with JSON metadata and schema versions, read without pickle, optionally memory-mapped;
* ``readers``: small readers (CSV rows, SHA-256).
"""
