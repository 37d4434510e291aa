//! `sdfreg batch PAIRS.csv --output RESULTS.jsonl`: many pairs on every core, one pair per
//! worker, each result appended to the output as one JSON line the moment it finishes
//! (`sdfreg_core::batch::log` documents the file), so a crash or Ctrl-C loses no finished pair;
//! run again, it resumes: rows already in the output are skipped.

use std::collections::{HashMap, VecDeque};
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::Isometry3;
use sdfreg_core::batch::log::{header_line, read_batch_log, BatchLog};
use sdfreg_core::{
    register_each_loading, Pair, PairTarget, RegisterSettings, Registration, SdfModel,
};

use crate::args::BatchArgs;
use crate::output::registration_json;

/// Some pairs failed (their lines in the output hold the errors); `main` exits with 3.
#[derive(Debug, thiserror::Error)]
#[error("{failed} of {total} pairs failed (their errors are in {output})")]
pub struct SomeFailed {
    pub failed: usize,
    pub total: usize,
    pub output: String,
}

/// One data row of the pairs file.
#[derive(Debug)]
struct Row {
    /// 1-based data row (headers and comments not counted), the key in the output.
    number: u64,
    /// The paths as written in the file, and resolved against its folder.
    source: String,
    target: String,
    source_path: PathBuf,
    target_path: PathBuf,
    /// For a target that is a stored model, the file's canonical path (as resolved when it has
    /// none): the key its rows share one loaded model by, however each spells it.
    model: Option<PathBuf>,
    init: Option<PathBuf>,
    /// The row's seed, or `--seed` when it gives none.
    seed: u64,
}

pub fn run(a: BatchArgs) -> Result<()> {
    if crate::same_file(&a.output, &a.pairs) {
        bail!(
            "{}: refusing to write the output over the pairs file",
            a.output.display()
        );
    }
    let settings = a.common.settings()?;
    let rows = read_pairs(&a.pairs, settings.seed)?;
    let pairs_name = a
        .pairs
        .canonicalize()
        .unwrap_or_else(|_| a.pairs.clone())
        .display()
        .to_string();
    let (file, done) = open_output(&a, &pairs_name, &rows, &settings)?;
    let earlier_failed = done.values().filter(|&&ok| !ok).count();
    let pending: Vec<&Row> = rows
        .iter()
        .filter(|r| !done.contains_key(&r.number))
        .collect();
    if !done.is_empty() {
        eprintln!(
            "sdfreg: {}: resuming: {} of {} pairs already done, {} to go",
            a.output.display(),
            done.len(),
            rows.len(),
            pending.len()
        );
    }
    let models = Models::default();
    let queue = Queue::new(&pending, &models);
    let bar = bar(pending.len() as u64);
    let out = Mutex::new(Output {
        file,
        path: &a.output,
        failed: 0,
        written: 0,
        error: None,
        bar: &bar,
        lines: ProgressLines::new(pending.len()),
    });
    let start = Instant::now();
    // Each worker reads its row's files (at the same time as the others); rows whose files
    // cannot be read are recorded as failed right away, the rest register.
    let read = |(row, model)| match load(row, model, &a) {
        Ok(pair) => Some((row, pair)),
        Err(e) => {
            models.ended(row, false);
            lock(&out).record(row, Err(format!("{e:#}")));
            None
        }
    };
    let stop = AtomicBool::new(false);
    register_each_loading(queue, read, &settings, a.common.threads, &stop, |row, r| {
        models.ended(row, true);
        let r = r.map_err(|e| {
            format!(
                "{:#}",
                crate::name_cloud(e.into(), &row.source_path, &row.target_path)
            )
        });
        let mut out = lock(&out);
        out.record(row, r);
        if out.error.is_some() {
            // The output cannot be written: start no more pairs.
            stop.store(true, std::sync::atomic::Ordering::Relaxed);
        }
    })?;
    bar.finish_and_clear();
    let out = out.into_inner().unwrap_or_else(|e| e.into_inner());
    if let Some(e) = out.error {
        return Err(e);
    }
    let seconds = start.elapsed().as_secs_f64();
    eprintln!(
        "sdfreg: {}: {} pairs registered, {} failed in {:.1} s ({:.2} pairs/s); {} done before",
        a.output.display(),
        out.written - out.failed,
        out.failed,
        seconds,
        out.written as f64 / seconds.max(1e-9),
        done.len()
    );
    let failed = out.failed + earlier_failed;
    if failed > 0 {
        return Err(SomeFailed {
            failed,
            total: rows.len(),
            output: a.output.display().to_string(),
        }
        .into());
    }
    Ok(())
}

/// Where finished pairs go: the output file (one line per pair, written and flushed whole)
/// and the progress bar.
struct Output<'a> {
    file: File,
    path: &'a Path,
    written: usize,
    failed: usize,
    /// The first write that failed; no line is written after it.
    error: Option<anyhow::Error>,
    bar: &'a ProgressBar,
    /// Progress as plain lines, when stderr is not a terminal (the bar is hidden then).
    lines: Option<ProgressLines>,
}

/// Progress as plain lines on stderr for logs (pipelines, cluster jobs), where a bar cannot
/// redraw: one line at each tenth of the pairs, and at least every [`Self::EVERY`].
struct ProgressLines {
    total: usize,
    start: Instant,
    last: Instant,
    /// The tenth of the pairs whose completion prints the next line.
    next_tenth: usize,
}

impl ProgressLines {
    /// The longest time between two lines.
    const EVERY: std::time::Duration = std::time::Duration::from_secs(60);

    /// Lines for `total` pairs, when stderr is not a terminal.
    fn new(total: usize) -> Option<Self> {
        use std::io::IsTerminal;
        let now = Instant::now();
        (total > 0 && !std::io::stderr().is_terminal()).then_some(Self {
            total,
            start: now,
            last: now,
            next_tenth: 1,
        })
    }

    /// Prints a line if `done` pairs complete a tenth, or the last line is old.
    fn update(&mut self, done: usize, failed: usize) {
        let now = Instant::now();
        let tenth = done * 10 / self.total;
        if tenth < self.next_tenth && now - self.last < Self::EVERY {
            return;
        }
        self.next_tenth = tenth + 1;
        self.last = now;
        let seconds = (now - self.start).as_secs_f64().max(1e-9);
        let rate = done as f64 / seconds;
        let left = (self.total - done) as f64 / rate.max(1e-9);
        eprintln!(
            "sdfreg batch: {done}/{} pairs ({failed} failed), {rate:.2} pairs/s, {} left",
            self.total,
            indicatif::HumanDuration(std::time::Duration::from_secs_f64(left.min(1e9)))
        );
    }
}

impl Output<'_> {
    fn record(&mut self, row: &Row, result: Result<Registration, String>) {
        if self.error.is_some() {
            return;
        }
        let mut line = serde_json::json!({
            "row": row.number,
            "source": row.source,
            "target": row.target,
            "seed": row.seed,
            "ok": result.is_ok(),
        });
        let fields = match &result {
            Ok(r) => registration_json(r),
            Err(e) => serde_json::json!({ "error": e }),
        };
        if let (Some(line), serde_json::Value::Object(fields)) = (line.as_object_mut(), fields) {
            line.extend(fields);
        }
        let text = line.to_string() + "\n";
        if let Err(e) = self
            .file
            .write_all(text.as_bytes())
            .and_then(|()| self.file.flush())
        {
            self.error = Some(anyhow::Error::new(e).context(self.path.display().to_string()));
            return;
        }
        self.written += 1;
        self.failed += usize::from(result.is_err());
        if self.failed > 0 {
            self.bar.set_message(format!("{} failed", self.failed));
        }
        self.bar.inc(1);
        if let Some(lines) = &mut self.lines {
            lines.update(self.written, self.failed);
        }
    }
}

fn lock<'m, T>(m: &'m Mutex<T>) -> std::sync::MutexGuard<'m, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// A progress bar with the rate and the time left, on stderr when it is a terminal.
fn bar(len: u64) -> ProgressBar {
    let bar = crate::progress_bar(len);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{bar:30}] {pos}/{len} pairs, {per_sec}, {eta} left {msg}",
        )
        .expect("a valid template")
        .progress_chars("=> "),
    );
    bar
}

/// The stored models a batch's rows are registered against, each loaded once, by the first
/// worker to read one of its rows (another reading one of its rows meanwhile waits for it),
/// and let go once the [`Queue`] has handed out its last row, so it is freed when that row's
/// registration ends: a batch over many models holds only those its rows in flight or still to
/// come need.
#[derive(Default)]
struct Models<'p> {
    /// Per model file with rows still to take (the [`Queue`] adds them and takes them out).
    left: Mutex<HashMap<&'p Path, Entry>>,
}

/// A model file with rows still to take: its model once loaded, and how its rows are going.
#[derive(Default)]
struct Entry {
    /// The model once loaded (an error for a file that cannot be loaded, given to each of its
    /// rows).
    cell: ModelCell,
    /// Rows read and not yet ended.
    running: usize,
    /// A registration against it has ended, so the caches a first registration builds in a
    /// model (the multi-start's baked grid, the local grid's corners, the polish planes at its
    /// points) are there: a further row of it starts at once instead of waiting for them.
    warm: bool,
}

type ModelCell = Arc<OnceLock<Result<Arc<SdfModel>, String>>>;

impl Models<'_> {
    /// The claimed model at `path`, loaded by the first row to ask for it.
    fn load(cell: &ModelCell, path: &Path) -> Result<Arc<SdfModel>, String> {
        cell.get_or_init(|| {
            SdfModel::load(path)
                .map(Arc::new)
                .map_err(|e| e.to_string())
        })
        .clone()
    }

    /// `row` has ended: `registered` when its registration ran (and built the model's caches),
    /// not when its files could not be read.
    fn ended(&self, row: &Row, registered: bool) {
        let mut left = lock(&self.left);
        if let Some(entry) = row.model.as_deref().and_then(|key| left.get_mut(key)) {
            entry.running = entry.running.saturating_sub(1);
            entry.warm |= registered;
        }
    }
}

/// The order the workers take the rows in, each with its model claimed (for
/// [`Models::load`]). A model's rows are taken together, from where its first row stands (so
/// it is loaded once and freed soon, where rows spread over the file kept it to the end). A
/// model's further rows wait until its first registration has ended: meanwhile a free worker
/// takes the next row of another model or cloud, and waits only when no other row is left (two
/// workers starting on one fresh model would both wait for the caches it builds, one doing
/// nothing).
struct Queue<'r, 'p> {
    /// Rows still to take: a model's rows in one group, a row against a cloud alone.
    groups: VecDeque<VecDeque<&'r Row>>,
    models: &'r Models<'p>,
}

impl<'r, 'p> Queue<'r, 'p> {
    /// `rows` in groups, each model file they name entered in `models`.
    fn new(rows: &[&'p Row], models: &'r Models<'p>) -> Self
    where
        'p: 'r,
    {
        let mut groups: Vec<VecDeque<&Row>> = Vec::new();
        let mut of_model: HashMap<&Path, usize> = HashMap::new();
        for &row in rows {
            match row.model.as_deref() {
                Some(key) if of_model.contains_key(key) => groups[of_model[key]].push_back(row),
                key => {
                    if let Some(key) = key {
                        of_model.insert(key, groups.len());
                        lock(&models.left).insert(key, Entry::default());
                    }
                    groups.push(VecDeque::from([row]));
                }
            }
        }
        Queue {
            groups: groups.into(),
            models,
        }
    }
}

impl<'r> Iterator for Queue<'r, '_> {
    type Item = (&'r Row, Option<ModelCell>);

    fn next(&mut self) -> Option<Self::Item> {
        let mut left = lock(&self.models.left);
        let ready = |group: &VecDeque<&Row>| {
            group.front().is_some_and(|row| {
                row.model
                    .as_deref()
                    .and_then(|key| left.get(key))
                    .is_none_or(|e| e.warm || e.running == 0)
            })
        };
        let k = self.groups.iter().position(ready).unwrap_or(0);
        let group = self.groups.get_mut(k)?;
        let row = group.pop_front()?;
        let last = group.is_empty();
        if last {
            self.groups.remove(k);
        }
        // The row's model claimed, and let go of after its last row.
        let model = row.model.as_deref().and_then(|key| {
            let entry = left.get_mut(key)?;
            entry.running += 1;
            let cell = Arc::clone(&entry.cell);
            if last {
                left.remove(key);
            }
            Some(cell)
        });
        Some((row, model))
    }
}

/// Reads a row's clouds and initial guess; `model` its target's claimed model (`None` for a
/// cloud).
fn load(row: &Row, model: Option<ModelCell>, a: &BatchArgs) -> Result<Pair<'static>> {
    let seed = row.seed;
    let source = crate::read_cloud(&row.source_path, &a.input, seed)?;
    let target = match model {
        Some(cell) => match Models::load(&cell, &row.target_path) {
            Ok(model) => PairTarget::SharedModel(model),
            Err(e) => bail!("{e}"),
        },
        None => PairTarget::Cloud(crate::read_cloud(&row.target_path, &a.input, seed)?.into()),
    };
    let init: Option<Isometry3<f64>> = row.init.as_deref().map(crate::read_matrix).transpose()?;
    Ok(Pair {
        source: source.into(),
        target,
        init,
        seed: Some(seed),
    })
}

/// The rows of the pairs file, `default_seed` for those that give none; any malformed row fails
/// the whole batch before it starts, naming the line.
fn read_pairs(path: &Path, default_seed: u64) -> Result<Vec<Row>> {
    let base = path.parent().unwrap_or(Path::new(""));
    let resolve = |p: &str| base.join(p);
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .from_path(path)
        .with_context(|| path.display().to_string())?;
    let mut rows = Vec::new();
    for (k, record) in reader.records().enumerate() {
        let record = record.with_context(|| path.display().to_string())?;
        let line = record.position().map_or(0, |p| p.line());
        let at = || format!("{}:{line}", path.display());
        if k == 0
            && record
                .get(0)
                .is_some_and(|f| f.eq_ignore_ascii_case("source"))
        {
            continue;
        }
        // A line of blanks (one empty field once trimmed) is skipped; a row of empty fields
        // (`,`) is a row without its source and target, refused below.
        if record.len() == 1 && record[0].is_empty() {
            continue;
        }
        if !(2..=4).contains(&record.len()) {
            bail!(
                "{}: expected 2 to 4 fields (source,target[,init[,seed]]), found {}",
                at(),
                record.len()
            );
        }
        let (source, target) = (&record[0], &record[1]);
        if source.is_empty() || target.is_empty() {
            bail!("{}: the source and the target must both be given", at());
        }
        let init = record.get(2).filter(|s| !s.is_empty()).map(resolve);
        let seed = match record.get(3).filter(|s| !s.is_empty()) {
            Some(s) => s.parse::<u64>().map_err(|_| {
                anyhow::anyhow!("{}: seed {s:?} is not a non-negative integer", at())
            })?,
            None => default_seed,
        };
        let target_path = resolve(target);
        let model = crate::is_model(&target_path).then(|| {
            target_path
                .canonicalize()
                .unwrap_or_else(|_| target_path.clone())
        });
        rows.push(Row {
            number: rows.len() as u64 + 1,
            source: source.to_string(),
            target: target.to_string(),
            source_path: resolve(source),
            target_path,
            model,
            init,
            seed,
        });
    }
    if rows.is_empty() {
        bail!("{}: no pairs listed", path.display());
    }
    Ok(rows)
}

/// Opens the output to append to: a new file with its header, or (resuming) an existing one
/// checked against this batch, with a last line cut short by a kill removed. Returns the
/// rows it already holds (and whether each registered).
fn open_output(
    a: &BatchArgs,
    pairs_name: &str,
    rows: &[Row],
    settings: &RegisterSettings,
) -> Result<(File, HashMap<u64, bool>)> {
    let path = &a.output;
    let context = || path.display().to_string();
    let existing = match std::fs::read(path) {
        Ok(bytes) if !a.force => Some(bytes),
        Ok(_) => None,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => return Err(anyhow::Error::new(e).context(context())),
    };
    let log = match &existing {
        Some(bytes) => read_batch_log(bytes, path)?,
        None => None,
    };
    let Some(log) = log else {
        let mut file = File::create(path).with_context(context)?;
        file.write_all(header_line(pairs_name, settings).as_bytes())
            .with_context(context)?;
        return Ok((file, HashMap::new()));
    };
    check_resumable(&log, path, pairs_name, rows, settings)?;
    let file = OpenOptions::new()
        .write(true)
        .open(path)
        .with_context(context)?;
    let len = existing.map_or(0, |b| b.len());
    if log.complete_len < len {
        eprintln!(
            "sdfreg: {}: dropping an incomplete last line ({} bytes) left by an interrupted run",
            path.display(),
            len - log.complete_len
        );
        file.set_len(log.complete_len as u64)
            .with_context(context)?;
    }
    let mut file = file;
    std::io::Seek::seek(&mut file, std::io::SeekFrom::End(0)).with_context(context)?;
    let done = log.finished.iter().map(|f| (f.row, f.ok)).collect();
    Ok((file, done))
}

/// A results file is resumed only by the batch that began it: the same pairs file, the same
/// rows, the same settings (the thread count aside).
fn check_resumable(
    log: &BatchLog,
    path: &Path,
    pairs_name: &str,
    rows: &[Row],
    settings: &RegisterSettings,
) -> Result<()> {
    let other = "pass --force to start it afresh, or choose another --output";
    if log.pairs != pairs_name {
        bail!(
            "{}: holds the results of {}, not of {pairs_name}; {other}",
            path.display(),
            log.pairs
        );
    }
    let groups = |s: &RegisterSettings| {
        let s = RegisterSettings {
            threads: 0,
            ..s.clone()
        };
        serde_json::to_value(s).unwrap_or_default()
    };
    let (then, now) = (groups(&log.settings), groups(settings));
    if then != now {
        let differ: Vec<&String> = then
            .as_object()
            .into_iter()
            .flatten()
            .filter(|(k, v)| now.get(k.as_str()) != Some(v))
            .map(|(k, _)| k)
            .collect();
        bail!(
            "{}: was begun with other settings (differing: {}); {other}",
            path.display(),
            differ
                .iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    let by_number: HashMap<u64, &Row> = rows.iter().map(|r| (r.number, r)).collect();
    for f in &log.finished {
        match by_number.get(&f.row) {
            Some(r) if r.source == f.source && r.target == f.target => {}
            Some(r) => bail!(
                "{}:{}: row {} was {} → {}, the pairs file now says {} → {}; {other}",
                path.display(),
                f.line,
                f.row,
                f.source,
                f.target,
                r.source,
                r.target
            ),
            None => bail!(
                "{}:{}: row {} is not in the pairs file any more; {other}",
                path.display(),
                f.line,
                f.row
            ),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;
    use sdfreg_core::sim::shapes::fibonacci_sphere;

    #[test]
    fn a_model_is_loaded_once_shared_by_its_rows_and_let_go_after_the_last() {
        let dir = tempfile::tempdir().unwrap();
        let target: Vec<Point3<f64>> = fibonacci_sphere(256)
            .iter()
            .map(|v| Point3::from(v.component_mul(&nalgebra::Vector3::new(1.0, 0.7, 0.5))))
            .collect();
        let mut settings = RegisterSettings::default();
        settings.fit.model_prefit_steps = 20;
        let fitted = SdfModel::fit(&target, &settings).unwrap();
        let (a, b, gone) = (
            dir.path().join("a.sdfm"),
            dir.path().join("b.sdfm"),
            dir.path().join("gone.sdfm"),
        );
        fitted.save(&a).unwrap();
        fitted.save(&b).unwrap();
        // Rows name a three times, b once and a missing model twice.
        let rows: Vec<Row> = (1..)
            .zip([&a, &b, &a, &gone, &a, &gone])
            .map(|(k, path)| row(k, path.to_str().unwrap()))
            .collect();
        let pending: Vec<&Row> = rows.iter().collect();
        let models = Models::default();
        let mut queue = Queue::new(&pending, &models);
        let mut take = |number: u64| {
            let (row, cell) = queue.next().unwrap();
            assert_eq!(row.number, number);
            Models::load(&cell.unwrap(), &row.target_path)
        };

        let first = take(1).unwrap();
        models.ended(&rows[0], true);
        let second = take(3).unwrap();
        assert!(
            Arc::ptr_eq(&first, &second),
            "a is loaded once, for all its rows"
        );
        assert_eq!(first.distance(&target), fitted.distance(&target));
        let held = Arc::downgrade(&first);
        drop((first, second));
        assert!(
            held.upgrade().is_some(),
            "a kept while a row of it is still to come"
        );
        let last = take(5).unwrap();
        assert!(!lock(&models.left).contains_key(a.as_path()));
        drop(last);
        assert!(held.upgrade().is_none(), "a freed after its last row");
        let only_b = take(2).unwrap();
        assert!(
            !lock(&models.left).contains_key(b.as_path()),
            "b has no row left"
        );
        let b_held = Arc::downgrade(&only_b);
        drop(only_b);
        assert!(b_held.upgrade().is_none(), "b freed after its last row");
        for (number, at) in [(4, 3), (6, 5)] {
            let e = take(number).unwrap_err();
            assert!(e.contains("gone.sdfm"), "{e}");
            models.ended(&rows[at], false);
        }
        assert!(lock(&models.left).is_empty());
        assert!(queue.next().is_none());
    }

    /// A row of the pairs file against `target`.
    fn row(number: u64, target: &str) -> Row {
        Row {
            number,
            source: "s.ply".into(),
            target: target.into(),
            source_path: "s.ply".into(),
            target_path: target.into(),
            model: crate::is_model(Path::new(target)).then(|| target.into()),
            init: None,
            seed: 0,
        }
    }

    /// The number of the row `queue` gives next, 0 when none is left.
    fn taken(queue: &mut Queue) -> u64 {
        queue.next().map_or(0, |(row, _)| row.number)
    }

    #[test]
    fn a_model_s_rows_are_taken_together_and_its_second_waits_for_its_first_to_end() {
        // Models a, b and e spread over the file, and three clouds.
        let targets = [
            "a.sdfm", "b.sdfm", "a.sdfm", "c.ply", "b.sdfm", "a.sdfm", "e.sdfm", "d.ply", "e.sdfm",
            "f.ply",
        ];
        let rows: Vec<Row> = (1..).zip(targets).map(|(k, t)| row(k, t)).collect();
        let pending: Vec<&Row> = rows.iter().collect();
        let models = Models::default();
        let mut queue = Queue::new(&pending, &models);
        let a = Path::new("a.sdfm");
        let (first, cell) = queue.next().unwrap();
        assert_eq!(first.number, 1);
        let a_cell = cell.expect("a model row comes with its model claimed");
        // a's first registration runs: the next worker takes b's row, then the cloud's, rather
        // than a second row of a.
        assert_eq!(taken(&mut queue), 2);
        assert_eq!(taken(&mut queue), 4, "a and b both still fresh");
        models.ended(&rows[0], true);
        models.ended(&rows[1], true);
        // Both have been registered against once: a's rows come next, together (row 6 before
        // b's row 5), then b's.
        let (third, cell) = queue.next().unwrap();
        assert_eq!(third.number, 3);
        assert!(
            Arc::ptr_eq(&a_cell, &cell.unwrap()),
            "one model for a's rows"
        );
        assert_eq!(taken(&mut queue), 6);
        assert!(
            !lock(&models.left).contains_key(a),
            "a let go after its last row"
        );
        assert_eq!(taken(&mut queue), 5);
        // e's first row, then the cloud d while e is fresh.
        assert_eq!(taken(&mut queue), 7);
        let (cloud, cell) = queue.next().unwrap();
        assert_eq!(
            (cloud.number, cell.is_none()),
            (8, true),
            "a cloud has no model"
        );
        // e's first row ended without a registration (its source could not be read): its next
        // row need not wait, and comes before the cloud f.
        models.ended(&rows[6], false);
        assert_eq!(taken(&mut queue), 9);
        assert_eq!(taken(&mut queue), 10);
        assert_eq!(taken(&mut queue), 0);
        assert!(lock(&models.left).is_empty());

        // With no other row to take, a fresh model's second row is taken at once.
        let rows = [row(1, "a.sdfm"), row(2, "a.sdfm")];
        let pending: Vec<&Row> = rows.iter().collect();
        let models = Models::default();
        let mut queue = Queue::new(&pending, &models);
        assert_eq!([taken(&mut queue), taken(&mut queue)], [1, 2]);
    }

    #[test]
    fn a_model_spelled_two_ways_in_the_pairs_file_is_loaded_once() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("sub")).unwrap();
        std::fs::write(dir.path().join("m.sdfm"), b"").unwrap();
        let pairs = dir.path().join("pairs.csv");
        std::fs::write(
            &pairs,
            "s.ply,m.sdfm\ns.ply,./m.sdfm\ns.ply,sub/../m.sdfm\ns.ply,gone.sdfm\n",
        )
        .unwrap();
        let rows = read_pairs(&pairs, 0).unwrap();
        let pending: Vec<&Row> = rows.iter().collect();
        let models = Models::default();
        let mut queue = Queue::new(&pending, &models);
        let (_, first) = queue.next().unwrap();
        models.ended(&rows[0], true);
        let cells: Vec<ModelCell> = [first, queue.next().unwrap().1, queue.next().unwrap().1]
            .into_iter()
            .map(Option::unwrap)
            .collect();
        assert!(
            cells.iter().all(|c| Arc::ptr_eq(c, &cells[0])),
            "m.sdfm, ./m.sdfm and sub/../m.sdfm share one model"
        );
        // A model that is not there keeps its path as resolved (its load then names it).
        let (row, cell) = queue.next().unwrap();
        assert_eq!(
            row.model.as_deref(),
            Some(dir.path().join("gone.sdfm").as_path())
        );
        assert!(cell.is_some());
        assert!(lock(&models.left).is_empty());
    }
}
