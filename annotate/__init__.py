"""Human labels of true outliers: SQLite store, labelling page, true accuracy."""
