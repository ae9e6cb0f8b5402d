"""``tactojax repair DIR``: rewrite a dataset without its corrupt chunks, saying what is lost."""

from __future__ import annotations

from tactojax.cli._table import format_table, write_json


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "repair", help="drop a dataset's corrupt chunks, keeping every intact record",
        description="Check every chunk of a dataset against its manifest (hash, archive, shapes). If some "
                    "are corrupt (truncated, modified, missing), rewrite the manifest atomically without "
                    "them, move their files to DIR/corrupt/, record the loss in the manifest's metadata "
                    "and print which chunks and how many records were lost.")
    parser.add_argument("dataset", help="dataset directory")
    parser.add_argument("--dry-run", action="store_true", help="only report what would be lost; change nothing")
    parser.add_argument("--json", metavar="PATH", help="also write the report as JSON")
    parser.set_defaults(run=run)


def run(args) -> int:
    from tactojax.cli._main import UserError
    from tactojax.io import DatasetLockedError, repair_dataset

    try:
        report = repair_dataset(args.dataset, dry_run=args.dry_run)
    except DatasetLockedError as error:
        raise UserError(str(error)) from None
    kept = f"{report.kept_records} records in {report.kept_chunks} chunks"
    if not report.lost:
        print(f"{args.dataset}: every chunk is intact ({kept}); nothing to repair")
    else:
        rows = [[chunk.file, chunk.count, f"{chunk.first_record}-{chunk.first_record + chunk.count - 1}",
                 chunk.reason, "-" if moved is None else str(moved)]
                for chunk, moved in zip(report.lost, report.moved_to, strict=True)]
        print(format_table(["corrupt chunk", "records", "record range", "problem", "moved to"], rows))
        verb = "would lose" if args.dry_run else "lost"
        print(f"{args.dataset}: {verb} {report.lost_records} records in {len(report.lost)} chunks; "
              f"{'would keep' if args.dry_run else 'kept'} {kept}"
              + ("" if args.dry_run else " (the loss is recorded in the manifest's metadata under 'repairs')"))
    if args.json:
        write_json(args.json, report.as_dict())
    return 0
