"""The job contract: what the supervisor and the worker services agree on, and nothing else.

Both sides import it; it imports neither. A service declares its job kinds here as data
(``kinds``), writes its handlers against the ``JobContext`` protocol (``context``) and says
how an attempt ended with the ``errors``; its commands refuse through ``cli.fail`` and its
benches write their results through ``bench``.
"""
