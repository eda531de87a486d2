"""``iem bench writeback``: the write-back scenario by scenario (:mod:`.command`), the
scenarios on the simulated cell (:mod:`.scenarios`), the real recording's cases
(:mod:`.real`), the scores (:mod:`.score`) and the figures (:mod:`.figures`).
"""
