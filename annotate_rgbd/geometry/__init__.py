"""Camera model, sensor noise, plane fits and plane transforms, and the exact medians they take
(:mod:`.statistics`): pure numpy, no files, no runs."""
