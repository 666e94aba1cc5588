"""``helicalib console DB``: the crew console of any campaign database, read-only."""

from __future__ import annotations

import argparse

from helicalib.commands._args import add_database


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("console", help="serve a read-only live web page of a campaign database",
                       description="Serve the crew console (field map, boards and frames, gate, acceptance, event "
                                   "log) of a campaign database, also of a campaign another process runs now: it "
                                   "opens the database read-only, never writes and never takes the owner lock, and "
                                   "the page updates by itself as the campaign records. Operator actions need the "
                                   "controller itself (run/check --arm --console). See docs/console.md.")
    add_database(p)
    p.add_argument("--campaign", type=int, default=None,
                   help="campaign id (default: the one the process holding the database runs, else the newest "
                        "running one, else the newest)")
    p.add_argument("--listen", metavar="[HOST:]PORT", default="8765",
                   help="address to serve on (default 8765 on 127.0.0.1; a host beyond loopback needs "
                        "--console-public)")
    p.add_argument("--console-public", action="store_true",
                   help="allow listening beyond loopback; every request then needs the token printed at start")
    p.add_argument("--field", default=None, help="field config to use instead of the one the campaign recorded")
    p.add_argument("--images", default=None, help="frames directory (default: the folder the campaign recorded at "
                                                   "its start, else images beside the database)")
    p.add_argument("--json", action="store_true", help="print the address as one JSON line instead of a sentence")
    p.set_defaults(func=run)


def run(args) -> int:
    import json
    import secrets
    import sys

    from helicalib.commands.status import shown_campaign
    from helicalib.console.app import Console, create_app
    from helicalib.console.server import ConsoleServer, parse_address, url
    from helicalib.console.view import Sources, reading
    from helicalib.errors import ConfigError
    from helicalib.geometry.sitetime import site_time
    from helicalib.report.data import find_config
    from helicalib.store.sqlite import Store, existing_database

    host, port = parse_address(args.listen, args.console_public, "--listen")
    path = existing_database(args.db)

    def reopen():
        return Store.open(path, args.images, readonly=True)  # a reader: never writes, never takes the lock

    store = reopen()
    try:
        with reading(store, args.campaign):
            campaigns = store.campaigns()
            if not campaigns:
                raise ConfigError(f"{args.db}: no campaign in this database yet")
            campaign, why = shown_campaign(store, campaigns, store.owner(), args.campaign)
            cfg, note = find_config(campaign, path, args.field)
    except BaseException:
        store.close()
        raise
    token = secrets.token_urlsafe(18) if args.console_public else None
    sources = Sources(store=store, cfg=cfg, campaign_id=campaign.id, site=site_time(cfg),
                      images_dir=store.images_dir if args.images else None)  # else where the campaign wrote them
    console = Console(sources, token=token, reopen=reopen,
                      title=f"helicalib · {cfg.site.name if cfg is not None else campaign.name}")
    server = ConsoleServer(create_app(console), host, port, "--listen")
    server.bind()
    address = url(host, server.port, token)
    if args.json:
        print(json.dumps({"event": "console", "url": address, "token": token, "campaign": campaign.id,
                          "campaign_name": campaign.name, "campaign_chosen": why, "database": str(path),
                          "config_note": note}), flush=True)
    else:
        print(f"console of campaign {campaign.id} ({campaign.name}; {why}) in {path}: {address} (read-only"
              + ("; the token is required on every request" if token else "; this machine only")
              + ("" if cfg is not None else f"; no field map: {note}") + "); Ctrl-C stops", file=sys.stderr,
              flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        console.close()
        sources.store.close()
        console.remove_cache()
    return 0
