"""``stereod view``: a web page of one rig, served from a Zenoh session of its own
(:mod:`.server`), with its page, script and style in ``static/`` (shipped with the package)."""
