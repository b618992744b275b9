"""The application: the ``livecap`` command, its commands, the source registry and the one place
that assembles stages and sinks."""
