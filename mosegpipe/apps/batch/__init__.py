"""Folders of clips (`moseg batch`): the plan, the local process pool, the Ray engine, the run."""
