"""Chaining the sub-policies (paper Sec. 3.2-3.3 and Algorithm 1).

- :mod:`~seqdex_drake.chaining.feasibility`: the transition feasibility function F (temporal attention model and
  the "w/o temporal" MLP), its training, the switching threshold h and score c = F / h, and its file format.
- :mod:`~seqdex_drake.chaining.terminal_buffer`: forward initialization's hand-off file of terminal states.
- :mod:`~seqdex_drake.chaining.tstar`: the T-STAR baseline's terminal-state discriminator.
- :mod:`~seqdex_drake.observation_spec` and :mod:`~seqdex_drake.atomic`: the observation spec recorded in
  every file, and the atomic file write they share.
"""
