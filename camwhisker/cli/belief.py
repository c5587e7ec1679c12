"""``camwhisker belief``: contact belief (eq. 1), contact flag and onsets of a signal table."""

from __future__ import annotations

from camwhisker.cli.common import CommandError

__all__ = ["add_belief"]


def add_belief(sub) -> None:
    from camwhisker.contact.belief import ETA_FACTOR, ETA_QUANTILE

    p = sub.add_parser(
        "belief",
        help="signal table -> contact belief (eq. 1), contact flag and onsets, no stage log",
        description="Add contact_b (eq. 1: clip(phi / eta - 1, 0, 1)) and contact (entered "
        "where contact_b reaches 1, left where it falls to 0) to a signal table, and list "
        "the onsets, refined back to where phi left the noise, in OUT.json. eta is "
        f"{ETA_FACTOR:g} x the {ETA_QUANTILE:g} quantile of phi over the rest frames the "
        "table's sidecar S.json names.",
    )
    p.add_argument("--signals", required=True, metavar="S.csv",
                   help="signal table (camwhisker batch, live, replay)")  # fmt: skip
    p.add_argument(
        "--out",
        required=True,
        metavar="B.csv",
        help="the signal table with contact_b and contact added; OUT.json beside it",
    )
    p.add_argument("--rest-frames", type=int, metavar="N",
                   help="the first N rows are at rest (a table without a sidecar); "
                        "default: the sidecar's rest frames")  # fmt: skip
    p.add_argument(
        "--eta-deg",
        type=float,
        metavar="X",
        help="eta as given (from no-contact trials), the rest frames unused",
    )
    p.set_defaults(func=_run_belief)


def _run_belief(args) -> int:
    from camwhisker.contact.belief_table import table_belief, write_belief_table

    if args.eta_deg is not None and not args.eta_deg > 0:
        raise CommandError(f"--eta-deg must be > 0, got {args.eta_deg}")
    if args.rest_frames is not None and args.rest_frames < 1:
        raise CommandError(f"--rest-frames must be >= 1, got {args.rest_frames}")
    belief = table_belief(args.signals, args.rest_frames, args.eta_deg)
    side = write_belief_table(belief, args.out)
    print(f"eta {belief.eta_deg:.4f} deg ({belief.eta_from}); {int(belief.flag.sum())} of "
          f"{belief.b.size} frames in contact, {len(belief.onsets)} onset(s)")  # fmt: skip
    for o in belief.onsets:
        print(f"onset frame {o.frame} (t {belief.t_s[o.frame]:.3f} s), b = 1 at frame "
              f"{o.detected_frame}, contact to frame {o.end_frame}")  # fmt: skip
    print(f"wrote {args.out}, {side}")
    return 0
