"""The patient's page on the home station: its server (:mod:`.app`), its messages, its game's
field and its host checks, and its own HTML, script and style sheet (``static/``)."""
