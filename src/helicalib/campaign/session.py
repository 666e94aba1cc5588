"""Live sessions (``helicalib run`` and ``helicalib check``): devices from the config, store, runner."""

from __future__ import annotations

import json

from helicalib.errors import ConfigError


def live_session(args, mode: str) -> int:
    """Open the store, connect the plant, resume or start a campaign, run it on APScheduler."""
    from rich.console import Console

    from helicalib.campaign.live import run_live
    from helicalib.campaign.runner import CampaignRunner
    from helicalib.config import load_field_config
    from helicalib.devices.camera_http import cameras_from_config
    from helicalib.devices.clock import make_clock
    from helicalib.devices.modbus import ModbusPlant
    from helicalib.geometry.sun import parse_time, to_unix_seconds
    from helicalib.store.sqlite import Store

    console = Console(stderr=True)
    cfg = load_field_config(args.field)
    ids = [s.strip() for s in args.heliostats.split(",")] if args.heliostats else None
    for hid in ids or ():
        cfg.heliostat(hid)
    store = Store.open(cfg.database_path, cfg.images_path)
    plant = ModbusPlant.from_config(cfg, armed=args.arm)
    try:
        clock = make_clock(cfg, plant)
        now = clock.now_s()
        if args.until:
            until_s = float(to_unix_seconds([parse_time(args.until)])[0])
        else:
            until_s = now + 86400.0 * (args.days if args.days is not None else 7.0)
        if until_s <= now:
            raise ConfigError(f"--until {args.until}: lies before the plant time now")
        resumed = store.unfinished_campaign(mode=mode) if mode == "live" else None
        if resumed is not None:
            campaign_id = resumed.id
            ids = [h.heliostat_id for h in store.campaign_heliostats(campaign_id)]
            console.print(f"resuming campaign {campaign_id} ({len(ids)} heliostats, "
                          f"{store.count_observations(campaign_id)} observations so far)")
        else:
            ids = ids or [h.id for h in cfg.heliostats]
            campaign_id = store.start_campaign(
                name=f"{mode} {cfg.site.name}", mode=mode, started_s=now,
                heliostats=[(hid, cfg.heliostat_index(hid), cfg.heliostat(hid).target) for hid in ids],
                config_path=str(cfg.source), settings={"armed": args.arm, "planner": args.planner,
                                                                     "refine": getattr(args, "refine", False)})
        if not args.arm:
            console.print("[yellow]not armed[/]: reading and planning only, nothing is written to the plant "
                          "(add --arm to calibrate)")
        cameras = cameras_from_config(cfg)
        runner = CampaignRunner(cfg, plant, cameras, clock, store, campaign_id, heliostat_ids=ids,
                                planner=args.planner, recheck=args.recheck, armed=args.arm,
                                refine=getattr(args, "refine", False))
        run_live(runner, until_s, done=(runner.rechecked if args.recheck else None))
        if clock.now_s() >= until_s or args.recheck:
            store.finish_campaign(campaign_id, clock.now_s())
        if mode == "check":
            rows = [{"heliostat": hid, "visits": runner.book.h[hid].visits,
                     "present_error_mrad": runner.book.h[hid].last_first_error_mrad} for hid in ids]
            if getattr(args, "json", False):
                print(json.dumps(rows, indent=2))
            else:
                for r in rows:
                    err = "not measured" if r["present_error_mrad"] is None else f"{r['present_error_mrad']:.2f} mrad"
                    print(f"{r['heliostat']}: present tracking error {err}")
        else:
            print(f"campaign {campaign_id}: {len(runner.accepted())}/{len(ids)} accepted, "
                  f"{store.count_observations(campaign_id)} observations in {cfg.database_path}")
    finally:
        plant.close()
        store.close()
    return 0
