"""The ``fit`` and ``design`` commands that ``fitting`` adds to ``jaximpact`` (``fitting.cli``)."""
