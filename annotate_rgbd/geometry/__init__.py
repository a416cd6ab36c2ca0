"""Camera model, sensor noise, plane fits and plane transforms: pure numpy, no files, no runs."""
