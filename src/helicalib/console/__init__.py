"""The crew console: a live web page of a campaign (``--console [HOST:]PORT``, ``helicalib console DB``).

* :mod:`.feed`: what the controller's process tells the page (its snapshots and events, kept
  behind a lock; the control loop never waits on the page);
* :mod:`.view`: the page's figures, read from the database through a read-only connection of
  its own (and, live, the newest snapshot);
* :mod:`.app`: the Starlette application (pages from Jinja2 templates shared with the report,
  server-sent events, operator actions, the token);
* :mod:`.server`: uvicorn in a thread, the address and token rules, and
  :func:`~helicalib.console.server.attach_console`, the one line a controller command adds.

``docs/console.md`` says what each panel shows and how the page is secured.
"""
