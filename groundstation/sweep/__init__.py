"""Monte-Carlo sweeps (``quadsitl sweep``): a spec of what varies (:mod:`.spec`), the batch engine that flies
every trial on the compiled equations of the plant and the autopilot (:mod:`.engine`), and the run that
splits the trials over worker processes and writes the table and its summary (:mod:`.run`)."""
