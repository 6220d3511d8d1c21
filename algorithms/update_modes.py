"""How SAC updates run (``update=`` of ``harness run``; :meth:`algorithms.core.sac.SAC.use_update`), in a module that
imports nothing, so that the command line can name the modes without loading torch.

- ``default``: hand-written gradients, per-member optimizer kernels (E seeds in one process bitwise equal E
  single-seed runs);
- ``static``: one fixed kernel sequence with a device mask (equal within rounding; what a GPU captures);
- ``compiled``: ``static`` through ``torch.compile`` (CUDA graphs on a GPU);
- ``autograd``: the same losses (:mod:`algorithms.core.losses`) through torch.autograd.
"""

UPDATES = ("default", "static", "compiled", "autograd")
