"""The daemon: one process that owns the gantry, with an HTTP API, an event stream and a live web view.

``gonio serve`` starts it (:func:`gonio.daemon.server.serve`). Modules, one idea each:

``queue``     the persistent campaign queue and the worker thread that runs its head on the gantry
``records``   a campaign as the daemon keeps it (``daemon.json``), and the checks a request passes
``planner``   planning and journaling submitted campaigns in a worker process, with a time limit
``gantry``    the gantry while no campaign runs: status, manual home/move, the emergency halt
``pacing``    a virtual clock that can also spend real time, so a person watching sees motion
``events``    the per-campaign event stream (server-sent events) read from the journal
``auth``      bearer tokens, the loopback rule, the rate of wrong tokens
``guard``     what a request must be before a route sees it: the daemon's Host names, same-origin
              writes, JSON bodies, size and time bounds
``models``    request and reply bodies (pydantic)
``app``       the FastAPI application (routes)
``server``    uvicorn, signals, logging: what ``gonio serve`` runs
``client``    the httpx client behind ``gonio submit|queue|watch|pause|resume|abort|halt|fetch``
``commands``  those commands and ``gonio serve`` on the command line (parsers and ``cmd_*``)
"""
