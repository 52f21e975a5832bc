"""The paper's evaluation (Tables I-V): test views, per-view runs, records, tables and the results store."""
