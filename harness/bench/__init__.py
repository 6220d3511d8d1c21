"""``harness bench``: throughput measurements, never timed tests: env steps (:mod:`.env`, also the products of
:func:`~.env.bench_matmul`), training steps (:mod:`.train`), one SAC update against its matmul ceiling (:mod:`.update`)
and the dashboard's page loads (:mod:`.app`)."""
