"""What a run writes besides masks: typed records (report.json, the journal), colours, statistics."""
