"""``camwhisker learn`` and ``camwhisker predict``: a time-series estimator trained on tables."""

from __future__ import annotations

from camwhisker.cli.common import CommandError

__all__ = ["add_learn", "add_predict"]


def _names(text: str | None, flag: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in (text or "").split(",") if n.strip())
    if len(set(names)) != len(names):
        raise CommandError(f"{flag}: a column named twice: {text}")
    return names


def add_learn(sub) -> None:
    from camwhisker.learn.series import SPLITS
    from camwhisker.learn.train import KINDS, TrainOptions

    d = TrainOptions()
    p = sub.add_parser(
        "learn",
        help="tables -> a model that estimates target columns from windows of input columns",
        description="Train a time-series estimator (docs/learn.md): from the last --window "
        "rows of the input columns to the target columns at the window's last row. Each "
        "table is one continuous recording at a fixed rate (windows never span two). "
        "Angle targets are learned on the circle. Validation windows (by default each "
        "table's last 20 %% of rows) choose the model's setting; the final model is then "
        "fitted on every row. The conv kind needs torch (the 'learn' extra).",
    )
    p.add_argument("--table", action="append", required=True, metavar="T.csv",
                   help="a table (CSV with a header); repeat once per recording")  # fmt: skip
    p.add_argument("--inputs", required=True, metavar="A,B,C", help="input columns")
    p.add_argument("--targets", metavar="X,Y", help="target columns (scalars)")
    p.add_argument("--angle-targets", metavar="Z",
                   help="target columns that are angles in degrees (periodic)")  # fmt: skip
    p.add_argument("--window", type=int, required=True, metavar="N",
                   help="rows per window, the last one the row estimated")  # fmt: skip
    p.add_argument("--out", required=True, metavar="MODEL", help="model directory to write")
    p.add_argument("--kind", choices=KINDS, default=d.kind,
                   help="knn: the nearest training windows (summary features); conv: a "
                        "causal convolutional network (default: %(default)s)")
    p.add_argument("--validation", choices=tuple(SPLITS), default=d.validation,
                   help="time: each table's last 20 %% of rows held out; tables: the last "
                        "tables, at least 20 %% of the rows (default: %(default)s)")
    p.add_argument("--epochs", type=int, default=d.epochs, metavar="N",
                   help="conv: most epochs (fewer when validation stops improving)")
    p.add_argument("--samples-per-epoch", type=int, default=d.samples_per_epoch, metavar="N",
                   help="conv: windows drawn per epoch (all, when the tables hold fewer)")
    p.add_argument("--seed", type=int, default=d.seed, help="random seed")
    p.set_defaults(func=_run_learn)


def _run_learn(args) -> int:
    from camwhisker.learn.modeldir import save_model
    from camwhisker.learn.series import Columns, read_series
    from camwhisker.learn.train import TrainOptions, learn

    columns = Columns(_names(args.inputs, "--inputs"), _names(args.targets, "--targets"),
                      _names(args.angle_targets, "--angle-targets"))  # fmt: skip
    if not columns.inputs or not columns.all_targets:
        raise CommandError("give at least one input and one target (--targets or "
                           "--angle-targets)")  # fmt: skip
    if set(columns.all_targets) & set(columns.inputs):
        raise CommandError("a column is both an input and a target")
    for flag, value in (("--window", args.window), ("--epochs", args.epochs),
                        ("--samples-per-epoch", args.samples_per_epoch)):  # fmt: skip
        if value < 1:
            raise CommandError(f"{flag} must be >= 1, got {value}")
    series = [read_series(t, columns, args.window, with_targets=True) for t in args.table]
    opts = TrainOptions(kind=args.kind, validation=args.validation, epochs=args.epochs,
                        samples_per_epoch=args.samples_per_epoch, seed=args.seed)  # fmt: skip
    trained = learn(series, columns, args.window, opts)
    out = save_model(args.out, trained.net, columns, args.window, trained.norm, trained.arch,
                     trained.summary)  # fmt: skip
    s = trained.summary
    chose = (f"k {trained.arch['k']}" if args.kind == "knn"
             else f"best epoch {s['best_epoch']} of {s['epochs_run']}")  # fmt: skip
    print(f"{args.kind}: {chose} on {s['validation_windows_scored']} validation windows "
          f"({args.validation} split), {s['train_s'] + s.get('final_s', 0.0):.1f} s; "
          f"validation errors:")
    for name, err in s["validation_errors"].items():
        print(f"  {name}: " + ", ".join(f"{k} {v:.4g}" for k, v in err.items()))
    print(f"final model fitted on all {s.get('final_training_rows', s['training_rows'])} "
          f"rows; wrote {out}")
    return 0


def add_predict(sub) -> None:
    p = sub.add_parser(
        "predict",
        help="a learned model's estimates for a table, one row per input row",
        description="Estimate a model's target columns (camwhisker learn) for every row of a "
        "table with its input columns; the first window - 1 rows are empty. Angles in "
        "degrees in (-180, 180].",
    )
    p.add_argument("--model", required=True, metavar="MODEL", help="model directory")
    p.add_argument("--table", required=True, metavar="T.csv", help="table with the inputs")
    p.add_argument("--out", required=True, metavar="P.csv", help="predictions (CSV)")
    p.set_defaults(func=_run_predict)


def _run_predict(args) -> int:
    from camwhisker.learn.modeldir import load_model
    from camwhisker.learn.predict import predict_table, write_predictions

    model = load_model(args.model)
    pred = predict_table(model, args.table)
    write_predictions(model, pred, args.out)
    print(f"{int(pred.shape[0] - model.window + 1)} of {pred.shape[0]} rows estimated "
          f"({', '.join(model.columns.all_targets)}); wrote {args.out}")
    return 0
