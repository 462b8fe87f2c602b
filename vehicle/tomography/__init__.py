"""Radio tomographic imaging: from the signal strengths of many radio links to an image of what stands between
them (the method and its sources: docs/rti.md). Beside ``vehicle.mapping``: the station images with it, the
experiments score with it; it needs numpy and scipy only."""
