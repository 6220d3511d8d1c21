"""``harness tune``: Optuna over an algorithm's settings. :mod:`.setup` reads the command and the search space,
:mod:`.studies` opens and summarises the study (journal file or RDB), :mod:`.trials` runs trials as ordinary run groups,
:mod:`.command` drives the workers."""
