"""Input and output: impact and result tables, scene files, output paths written atomically, the
compilation cache, and the ``jaximpact show`` report."""
