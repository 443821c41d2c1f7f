"""Studies over many runs: sweeps (`batch/`: plan, runner on local processes or Dask, store),
the report document (`document/`), the seeds' experiments (`replications/`) and the benchmarks
(`benchmarks/`). Their commands live in `cli/`."""
