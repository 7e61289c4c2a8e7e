"""Stored reference encodings and searching them: the storage formats and blockwise similarities
(``encodings``), row reads of a memory-mapped map (``rows``), the coarse whole-route search (``coarse``)."""
