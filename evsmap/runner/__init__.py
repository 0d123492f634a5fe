"""The matrix runner: expands the paper's tables into cells, runs them (timing cells each in a
fresh process, the rest in a process pool), stores one record per cell as it finishes, resumes an
interrupted run and caches segmentation outputs."""
