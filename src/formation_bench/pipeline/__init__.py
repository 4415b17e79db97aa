"""The run pipeline: what a closed-loop run is (:mod:`.spec`), the one path that executes it
(:mod:`.runner`), what it leaves (:mod:`.record`, :mod:`.outputs`), where and by what it was
made (:mod:`.provenance`), and the boundary checks and staged output folders around it
(:mod:`.checks`, :mod:`.staging`, :mod:`.interrupts`)."""
