//! `scl study report`: the participants' files merged into the paper's tables, figures and
//! tests.
//!
//! Only final attempts count (rows not marked `repeated`). Per task and condition: successes
//! (of attempts), the completion percentages; per task, item and condition: the Likert
//! answers and the NASA-TLX subscales. Each measure is tested across conditions with
//! Kruskal-Wallis (ties corrected) and, where it is significant (p < [`ALPHA`]), with Dunn's
//! pairwise test, Holm-adjusted ([`learning::experiments::stats`]).

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use learning::experiments::stats::{self, RankTests};

use crate::StudyError;
use crate::data::{AnswerRow, Outcome, QUESTIONNAIRE, TRIALS, TrialRow, read_rows};
use crate::diagnose::{DIAGNOSIS, DiagnosisRow};

/// The significance level of the tests.
pub const ALPHA: f64 = 0.05;

/// Every participant's rows, merged.
#[derive(Debug, Clone, Default)]
pub struct Data {
    /// The attempts.
    pub trials: Vec<TrialRow>,
    /// The answers.
    pub answers: Vec<AnswerRow>,
    /// Why each simulated attempt ended where it did (`diagnosis.csv`; none for people).
    pub diagnoses: Vec<DiagnosisRow>,
}

impl Data {
    /// Reads `trials.csv` and `questionnaire.csv` of each directory; a participant found in
    /// two directories is refused (their rows would count twice).
    pub fn load(dirs: &[PathBuf]) -> Result<Self, StudyError> {
        let mut data = Data::default();
        let mut owner: BTreeMap<String, PathBuf> = BTreeMap::new();
        for dir in dirs {
            let trials: Vec<TrialRow> = read_rows(&dir.join(TRIALS))?;
            let answers: Vec<AnswerRow> = read_rows(&dir.join(QUESTIONNAIRE))?;
            let diagnoses: Vec<DiagnosisRow> = read_rows(&dir.join(DIAGNOSIS))?;
            if trials.is_empty() && answers.is_empty() {
                return Err(StudyError::Data {
                    path: dir.clone(),
                    reason: format!("has neither {TRIALS} nor {QUESTIONNAIRE}"),
                });
            }
            let here: BTreeSet<&String> = trials
                .iter()
                .map(|t| &t.participant)
                .chain(answers.iter().map(|a| &a.participant))
                .collect();
            for p in here {
                if let Some(first) = owner.insert(p.clone(), dir.clone()) {
                    return Err(StudyError::Data {
                        path: dir.clone(),
                        reason: format!(
                            "participant {p} is also in {}: each participant once",
                            first.display()
                        ),
                    });
                }
            }
            data.trials.extend(trials);
            data.answers.extend(answers);
            data.diagnoses.extend(diagnoses);
        }
        Ok(data)
    }
}

/// One measure tested across the conditions.
#[derive(Debug, Clone)]
pub struct Tested {
    /// The task.
    pub task: String,
    /// What was measured (`completion %`, a Likert item, a TLX subscale).
    pub measure: String,
    /// `completion`, `likert` or `tlx`.
    pub kind: String,
    /// Each condition's values, in [`Report::conditions`] order.
    pub values: Vec<Vec<f64>>,
    /// Kruskal-Wallis and Dunn; `None` when there is nothing to rank (too few groups, all
    /// values equal).
    pub tests: Option<RankTests>,
}

impl Tested {
    /// Whether Kruskal-Wallis is significant.
    pub fn significant(&self) -> bool {
        self.tests.as_ref().is_some_and(|t| t.kruskal.p < ALPHA)
    }

    /// Conditions that differ from condition `reference` after Holm's adjustment (only when
    /// Kruskal-Wallis is significant).
    pub fn differ_from(&self, reference: usize) -> Vec<usize> {
        let Some(t) = self.tests.as_ref().filter(|_| self.significant()) else {
            return Vec::new();
        };
        t.dunn
            .iter()
            .filter(|d| d.p_holm < ALPHA && (d.a == reference || d.b == reference))
            .map(|d| if d.a == reference { d.b } else { d.a })
            .collect()
    }
}

/// Successes of one task and condition.
#[derive(Debug, Clone, PartialEq)]
pub struct Successes {
    /// The task.
    pub task: String,
    /// The condition.
    pub condition: String,
    /// Successful final attempts.
    pub successes: usize,
    /// Final attempts.
    pub attempts: usize,
}

/// The analysed study.
#[derive(Debug, Clone)]
pub struct Report {
    /// The study's name(s).
    pub study: String,
    /// The tasks, in the order of the data.
    pub tasks: Vec<String>,
    /// The conditions by name, ordered by their blind labels.
    pub conditions: Vec<String>,
    /// The participants.
    pub participants: Vec<String>,
    /// Per task and condition.
    pub successes: Vec<Successes>,
    /// Every tested measure: completion per task, then each Likert item, then each TLX
    /// subscale, per task.
    pub measures: Vec<Tested>,
    /// The condition the radar's stars compare against.
    pub reference: usize,
    /// Why the failed final attempts failed, per task and condition (simulated participants
    /// only: their `diagnosis.csv`).
    pub failures: Vec<Failures>,
}

/// The failed final attempts of one task and condition, from their diagnoses.
#[derive(Debug, Clone, PartialEq)]
pub struct Failures {
    /// The task.
    pub task: String,
    /// The condition.
    pub condition: String,
    /// Failed final attempts with a diagnosis.
    pub failed: usize,
    /// The subgoal never done, with how many attempts stopped before it, most first.
    pub stuck_at: Vec<(String, usize)>,
    /// The median of the closest the tool came to it (m).
    pub median_closest_m: Option<f64>,
    /// The safety rules that acted, ticks summed over these attempts, most first.
    pub safety: Vec<(String, u64)>,
}

/// [`Failures`] of the failed final attempts among `diagnoses`.
fn failures(
    finals: &[&TrialRow],
    diagnoses: &[DiagnosisRow],
    tasks: &[String],
    conditions: &[String],
) -> Vec<Failures> {
    let finals: BTreeSet<(&str, &str, &str, u32)> = finals
        .iter()
        .map(|t| {
            (
                t.participant.as_str(),
                t.task.as_str(),
                t.label.as_str(),
                t.attempt,
            )
        })
        .collect();
    let is_final = |d: &DiagnosisRow| {
        finals.contains(&(
            d.participant.as_str(),
            d.task.as_str(),
            d.label.as_str(),
            d.attempt,
        ))
    };
    let mut out = Vec::new();
    for task in tasks {
        for c in conditions {
            let rows: Vec<&DiagnosisRow> = diagnoses
                .iter()
                .filter(|d| {
                    &d.task == task
                        && &d.condition == c
                        && d.outcome != Outcome::Success
                        && is_final(d)
                })
                .collect();
            if rows.is_empty() {
                continue;
            }
            let mut stuck: BTreeMap<&str, usize> = BTreeMap::new();
            let mut safety: BTreeMap<String, u64> = BTreeMap::new();
            let mut closest = Vec::new();
            for d in &rows {
                *stuck.entry(d.next.as_str()).or_default() += 1;
                closest.extend(d.closest_m);
                // `position 120, acceleration 8`
                for part in d.safety.split(", ") {
                    if let Some((rule, n)) = part.rsplit_once(' ')
                        && let Ok(n) = n.parse::<u64>()
                    {
                        *safety.entry(rule.to_owned()).or_default() += n;
                    }
                }
            }
            let mut stuck_at: Vec<(String, usize)> = stuck
                .into_iter()
                .map(|(k, n)| (if k.is_empty() { "-" } else { k }.to_owned(), n))
                .collect();
            stuck_at.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
            let mut safety: Vec<(String, u64)> = safety.into_iter().collect();
            safety.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
            out.push(Failures {
                task: task.clone(),
                condition: c.clone(),
                failed: rows.len(),
                stuck_at,
                median_closest_m: (!closest.is_empty()).then(|| median(&closest)),
                safety,
            });
        }
    }
    out
}

/// Analyses `data`; `reference` names the condition the Likert radar compares against
/// (default: the first by label).
pub fn analyse(data: &Data, reference: Option<&str>) -> Result<Report, StudyError> {
    let finals: Vec<&TrialRow> = data.trials.iter().filter(|t| !t.repeated).collect();
    let tasks = tasks_of(&finals, data);
    let by_label: BTreeMap<&str, &str> = finals
        .iter()
        .map(|t| (t.label.as_str(), t.condition.as_str()))
        .chain(
            data.answers
                .iter()
                .map(|a| (a.label.as_str(), a.condition.as_str())),
        )
        .collect();
    let mut conditions: Vec<String> = Vec::new();
    for c in by_label.values() {
        if !conditions.iter().any(|x| x == c) {
            conditions.push((*c).to_owned());
        }
    }
    let reference = match reference {
        None => 0,
        Some(r) => conditions.iter().position(|c| c == r).ok_or_else(|| {
            StudyError::Report(format!(
                "--reference {r}: no such condition; the data has {}",
                conditions.join(", ")
            ))
        })?,
    };
    let participants: BTreeSet<String> = finals
        .iter()
        .map(|t| t.participant.clone())
        .chain(data.answers.iter().map(|a| a.participant.clone()))
        .collect();
    let study: BTreeSet<&str> = finals
        .iter()
        .map(|t| t.study.as_str())
        .chain(data.answers.iter().map(|a| a.study.as_str()))
        .collect();
    let mut successes = Vec::new();
    let mut measures = Vec::new();
    for task in &tasks {
        let mut completion = Vec::new();
        for c in &conditions {
            let rows: Vec<&&TrialRow> = finals
                .iter()
                .filter(|t| &t.task == task && &t.condition == c)
                .collect();
            successes.push(Successes {
                task: task.clone(),
                condition: c.clone(),
                successes: rows
                    .iter()
                    .filter(|t| t.outcome == Outcome::Success)
                    .count(),
                attempts: rows.len(),
            });
            completion.push(rows.iter().map(|t| t.completion_pct).collect::<Vec<f64>>());
        }
        if completion.iter().any(|v| !v.is_empty()) {
            measures.push(tested(task, "completion %", "completion", completion));
        }
        measures.extend(answer_measures(data, task, &conditions));
    }
    let failures = failures(&finals, &data.diagnoses, &tasks, &conditions);
    Ok(Report {
        study: study.into_iter().collect::<Vec<_>>().join(", "),
        tasks,
        conditions,
        participants: participants.into_iter().collect(),
        successes,
        measures,
        reference,
        failures,
    })
}

/// The tasks of the final attempts and the answers, in order of first appearance.
fn tasks_of(finals: &[&TrialRow], data: &Data) -> Vec<String> {
    let mut tasks: Vec<String> = Vec::new();
    for t in finals
        .iter()
        .map(|t| &t.task)
        .chain(data.answers.iter().map(|a| &a.task))
    {
        if !tasks.contains(t) {
            tasks.push(t.clone());
        }
    }
    tasks
}

/// The questionnaire measures of `task`: each Likert item and TLX subscale, its answers per
/// condition.
fn answer_measures(data: &Data, task: &str, conditions: &[String]) -> Vec<Tested> {
    let mut measures = Vec::new();
    for kind in ["likert", "tlx"] {
        let mut items: Vec<&str> = Vec::new();
        for a in data
            .answers
            .iter()
            .filter(|a| a.task == task && a.kind == kind)
        {
            if !items.contains(&a.item.as_str()) {
                items.push(&a.item);
            }
        }
        for item in items {
            let values = conditions
                .iter()
                .map(|c| {
                    data.answers
                        .iter()
                        .filter(|a| {
                            a.task == task && a.kind == kind && a.item == item && &a.condition == c
                        })
                        .map(|a| f64::from(a.value))
                        .collect()
                })
                .collect();
            measures.push(tested(task, item, kind, values));
        }
    }
    measures
}

fn tested(task: &str, measure: &str, kind: &str, values: Vec<Vec<f64>>) -> Tested {
    let refs: Vec<&[f64]> = values.iter().map(Vec::as_slice).collect();
    Tested {
        task: task.to_owned(),
        measure: measure.to_owned(),
        kind: kind.to_owned(),
        tests: stats::rank_tests(&refs),
        values,
    }
}

/// The median of `v` (NaN when empty).
pub fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        stats::median(v)
    }
}

/// The mean of `v` (NaN when empty).
pub fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// Writes the tables (CSV), the figures (PNG and SVG) and `summary.md` into `out`; returns
/// the files written.
pub fn write(r: &Report, out: &Path) -> Result<Vec<PathBuf>, StudyError> {
    std::fs::create_dir_all(out).map_err(|source| StudyError::Write {
        path: out.to_owned(),
        source,
    })?;
    let mut files = vec![
        write_table(
            out.join("successes.csv"),
            &["task", "condition", "successes", "attempts"],
            success_rows(r),
        )?,
        write_table(
            out.join("measures.csv"),
            &[
                "task",
                "kind",
                "measure",
                "condition",
                "n",
                "median",
                "mean",
                "q1",
                "q3",
            ],
            measure_rows(r),
        )?,
        write_table(
            out.join("tests.csv"),
            &[
                "task",
                "kind",
                "measure",
                "test",
                "a",
                "b",
                "statistic",
                "df",
                "n",
                "p",
                "p_holm",
            ],
            test_rows(r),
        )?,
    ];
    files.extend(crate::figures::write_all(r, out)?);
    let p = out.join("summary.md");
    std::fs::write(&p, summary(r)).map_err(|source| StudyError::Write {
        path: p.clone(),
        source,
    })?;
    files.push(p);
    Ok(files)
}

/// Writes a CSV table at `p`: the header, then the rows; returns `p`.
fn write_table(p: PathBuf, header: &[&str], rows: Vec<Vec<String>>) -> Result<PathBuf, StudyError> {
    let werr = |e: csv::Error| StudyError::Data {
        path: p.clone(),
        reason: e.to_string(),
    };
    let mut w = csv::Writer::from_path(&p).map_err(werr)?;
    w.write_record(header).map_err(werr)?;
    for row in rows {
        w.write_record(row).map_err(werr)?;
    }
    w.flush().map_err(|source| StudyError::Write {
        path: p.clone(),
        source,
    })?;
    Ok(p)
}

/// `successes.csv`'s rows: the successes and attempts per task and condition.
fn success_rows(r: &Report) -> Vec<Vec<String>> {
    r.successes
        .iter()
        .map(|s| {
            vec![
                s.task.clone(),
                s.condition.clone(),
                s.successes.to_string(),
                s.attempts.to_string(),
            ]
        })
        .collect()
}

/// `measures.csv`'s rows: each measure's count, median, mean and quartiles per condition.
fn measure_rows(r: &Report) -> Vec<Vec<String>> {
    let mut rows = Vec::new();
    for m in &r.measures {
        for (c, v) in r.conditions.iter().zip(&m.values) {
            let q = |x: f64| {
                if v.is_empty() {
                    f64::NAN
                } else {
                    stats::quantile(v, x)
                }
            };
            rows.push(vec![
                m.task.clone(),
                m.kind.clone(),
                m.measure.clone(),
                c.clone(),
                v.len().to_string(),
                fmt(median(v)),
                fmt(mean(v)),
                fmt(q(0.25)),
                fmt(q(0.75)),
            ]);
        }
    }
    rows
}

/// `tests.csv`'s rows: each measure's Kruskal-Wallis test, then (if significant) Dunn's
/// pairs.
fn test_rows(r: &Report) -> Vec<Vec<String>> {
    let mut rows = Vec::new();
    for m in &r.measures {
        let Some(t) = &m.tests else { continue };
        let k = &t.kruskal;
        rows.push(vec![
            m.task.clone(),
            m.kind.clone(),
            m.measure.clone(),
            "kruskal-wallis".into(),
            String::new(),
            String::new(),
            fmt(k.h),
            k.df.to_string(),
            k.n.to_string(),
            fmt(k.p),
            String::new(),
        ]);
        if m.significant() {
            for d in &t.dunn {
                rows.push(vec![
                    m.task.clone(),
                    m.kind.clone(),
                    m.measure.clone(),
                    "dunn".into(),
                    r.conditions[d.a].clone(),
                    r.conditions[d.b].clone(),
                    fmt(d.z),
                    String::new(),
                    (m.values[d.a].len() + m.values[d.b].len()).to_string(),
                    fmt(d.p),
                    fmt(d.p_holm),
                ]);
            }
        }
    }
    rows
}

fn fmt(x: f64) -> String {
    if x.is_finite() {
        format!("{x:.6}")
    } else {
        String::new()
    }
}

/// The summary: counts, then each test with the counts it used.
pub fn summary(r: &Report) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# {}\n", r.study);
    let _ = writeln!(
        s,
        "{} participants ({}); conditions {}; final attempts only (repeated ones left out). \
         Tests: Kruskal-Wallis across conditions (ties corrected); where p < {ALPHA}, Dunn's \
         pairwise test with Holm's adjustment.\n",
        r.participants.len(),
        r.participants.join(", "),
        r.conditions.join(", ")
    );
    let _ = writeln!(s, "## Successes\n");
    let _ = writeln!(s, "| task | {} |", r.conditions.join(" | "));
    let _ = writeln!(s, "|---|{}", "---|".repeat(r.conditions.len()));
    for task in &r.tasks {
        let cells: Vec<String> = r
            .successes
            .iter()
            .filter(|x| &x.task == task)
            .map(|x| format!("{} / {}", x.successes, x.attempts))
            .collect();
        let _ = writeln!(s, "| {task} | {} |", cells.join(" | "));
    }
    if !r.failures.is_empty() {
        push_failures(&mut s, r);
    }
    for task in &r.tasks {
        let _ = writeln!(s, "\n## {task}\n");
        for m in r.measures.iter().filter(|m| &m.task == task) {
            push_measure(&mut s, r, m);
        }
    }
    let checked: Vec<Claim> = claims(r)
        .into_iter()
        .filter(|c| c.supported.is_some())
        .collect();
    if !checked.is_empty() {
        let _ = writeln!(s, "\n## The paper's claims\n");
        for c in checked {
            let verdict = if c.supported == Some(true) {
                "supported"
            } else {
                "not supported"
            };
            let _ = writeln!(s, "- **{}**: {verdict}. {}", c.claim, c.evidence);
        }
    }
    s
}

/// The summary's table of why the failed final attempts failed.
fn push_failures(s: &mut String, r: &Report) {
    let _ = writeln!(
        s,
        "\n## Why attempts failed\n\nThe failed final attempts' `{DIAGNOSIS}`: the subgoal \
         they never did (how many stopped before it), the median of the closest the tool \
         came to it, and the safety rules that acted most (ticks, summed).\n"
    );
    let _ = writeln!(
        s,
        "| task | condition | failed | never done | closest, median | safety acted |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|");
    for f in &r.failures {
        let stuck: Vec<String> = f
            .stuck_at
            .iter()
            .map(|(g, n)| format!("{g} ({n})"))
            .collect();
        let safety: Vec<String> = f
            .safety
            .iter()
            .take(3)
            .map(|(rule, n)| format!("{rule} {n}"))
            .collect();
        let closest = f
            .median_closest_m
            .map(|m| format!("{:.1} cm", m * 100.0))
            .unwrap_or_else(|| "-".into());
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {closest} | {} |",
            f.task,
            f.condition,
            f.failed,
            stuck.join(", "),
            safety.join(", ")
        );
    }
}

/// The summary's line for measure `m`: its groups, then its tests.
fn push_measure(s: &mut String, r: &Report, m: &Tested) {
    let counts: Vec<String> = r
        .conditions
        .iter()
        .zip(&m.values)
        .map(|(c, v)| format!("{c} n={} median {}", v.len(), short(median(v))))
        .collect();
    let what = match m.kind.as_str() {
        "likert" => format!("Likert \"{}\"", m.measure),
        "tlx" => format!("NASA-TLX {}", m.measure),
        _ => m.measure.clone(),
    };
    let _ = write!(s, "- **{what}** ({}): ", counts.join("; "));
    match &m.tests {
        None => {
            let _ = writeln!(s, "not tested (fewer than two groups, or no spread).");
        }
        Some(t) => {
            let k = &t.kruskal;
            let _ = write!(
                s,
                "Kruskal-Wallis H({}) = {:.3}, p = {:.4}, N = {}",
                k.df, k.h, k.p, k.n
            );
            if m.significant() {
                let pairs: Vec<String> = t
                    .dunn
                    .iter()
                    .map(|d| {
                        format!(
                            "{} vs {} z = {:.3}, p_holm = {:.4}{}",
                            r.conditions[d.a],
                            r.conditions[d.b],
                            d.z,
                            d.p_holm,
                            if d.p_holm < ALPHA { " *" } else { "" }
                        )
                    })
                    .collect();
                let _ = writeln!(s, "; Dunn (Holm): {}.", pairs.join("; "));
            } else {
                let _ = writeln!(s, "; not significant, no pairwise test.");
            }
        }
    }
}

/// A claim of the paper checked on the data.
#[derive(Debug, Clone, PartialEq)]
pub struct Claim {
    /// The claim as the paper makes it.
    pub claim: &'static str,
    /// Whether the data supports it (`None`: the data lacks the task or the conditions).
    pub supported: Option<bool>,
    /// The evidence: counts, the test and its p values, and how the verdict was reached.
    pub evidence: String,
}

/// The condition called `name` (case and `-`/`_`/space insensitive; `modeswitch` is mode
/// switching).
fn condition(r: &Report, names: &[&str]) -> Option<usize> {
    let norm = |s: &str| {
        s.chars()
            .filter(|c| c.is_ascii_alphanumeric())
            .collect::<String>()
            .to_ascii_lowercase()
    };
    r.conditions
        .iter()
        .position(|c| names.iter().any(|n| norm(c) == norm(n)))
}

/// The completion measure of `task`.
fn completion<'a>(r: &'a Report, task: &str) -> Option<&'a Tested> {
    r.measures
        .iter()
        .find(|m| m.task == task && m.kind == "completion")
}

/// Dunn's Holm-adjusted p between conditions `a` and `b` (only when Kruskal-Wallis is
/// significant) and whether `a`'s mean completion is the higher.
fn pair(m: &Tested, a: usize, b: usize) -> (Option<f64>, bool) {
    let higher = mean(&m.values[a]) > mean(&m.values[b]);
    let p = m
        .tests
        .as_ref()
        .filter(|_| m.significant())
        .and_then(|t| {
            t.dunn
                .iter()
                .find(|d| (d.a, d.b) == (a, b) || (d.a, d.b) == (b, a))
        })
        .map(|d| d.p_holm);
    (p, higher)
}

fn kw(m: &Tested) -> String {
    match &m.tests {
        Some(t) => format!(
            "Kruskal-Wallis on completion H({}) = {:.3}, p = {:.4}, N = {}",
            t.kruskal.df, t.kruskal.h, t.kruskal.p, t.kruskal.n
        ),
        None => "completion not tested (no spread)".into(),
    }
}

fn counts(r: &Report, task: &str) -> String {
    r.successes
        .iter()
        .filter(|s| s.task == task)
        .map(|s| format!("{} {}/{}", s.condition, s.successes, s.attempts))
        .collect::<Vec<_>>()
        .join(", ")
}

fn dunn_text(r: &Report, m: &Tested, a: usize, b: usize) -> String {
    let (p, higher) = pair(m, a, b);
    let who = if higher {
        &r.conditions[a]
    } else {
        &r.conditions[b]
    };
    match p {
        Some(p) => format!(
            "Dunn {} vs {} p_holm = {p:.4} ({who} higher)",
            r.conditions[a], r.conditions[b]
        ),
        None => format!(
            "{} vs {}: no pairwise test (Kruskal-Wallis not significant; {who} higher mean)",
            r.conditions[a], r.conditions[b]
        ),
    }
}

/// The paper's four claims about its user studies, each checked on the data with the rank
/// tests on completion (Kruskal-Wallis, then Dunn with Holm at [`ALPHA`]).
pub fn claims(r: &Report) -> Vec<Claim> {
    let scl = condition(r, &["SCL"]);
    let pca = condition(r, &["PCA"]);
    let cae = condition(r, &["CAE"]);
    let modes = condition(r, &["mode switching", "modeswitch"]);
    vec![
        claim_scl_pick_and_place(r, scl, pca, cae),
        claim_pca_table_cleaning(r, pca),
        claim_scl_pouring(r, scl, modes),
        claim_cae_outside(r, scl, cae),
    ]
}

/// Whether condition `a` is significantly above condition `b` on measure `m`.
fn sig_better(m: &Tested, a: usize, b: usize) -> bool {
    let (p, higher) = pair(m, a, b);
    higher && p.is_some_and(|p| p < ALPHA)
}

/// The claim that SCL beats PCA and CAE on pick-and-place.
fn claim_scl_pick_and_place(
    r: &Report,
    scl: Option<usize>,
    pca: Option<usize>,
    cae: Option<usize>,
) -> Claim {
    let claim = "SCL beats PCA and CAE on pick-and-place";
    match (completion(r, "pick-and-place"), scl, pca, cae) {
        (Some(m), Some(s), Some(p), Some(c)) => Claim {
            claim,
            supported: Some(sig_better(m, s, p) && sig_better(m, s, c)),
            evidence: format!(
                "successes {}; {}; {}; {}. Supported when SCL's completion is significantly \
                 higher than both.",
                counts(r, "pick-and-place"),
                kw(m),
                dunn_text(r, m, s, p),
                dunn_text(r, m, s, c)
            ),
        },
        _ => Claim {
            claim,
            supported: None,
            evidence: "the data lacks pick-and-place or one of SCL, PCA, CAE".into(),
        },
    }
}

/// The claim that PCA does well on table cleaning.
fn claim_pca_table_cleaning(r: &Report, pca: Option<usize>) -> Claim {
    let claim = "PCA does well on table cleaning";
    match (completion(r, "table-cleaning"), pca) {
        (Some(m), Some(p)) => {
            let beaten: Vec<&str> = (0..r.conditions.len())
                .filter(|&o| o != p && sig_better(m, o, p))
                .map(|o| r.conditions[o].as_str())
                .collect();
            let s = r
                .successes
                .iter()
                .find(|s| s.task == "table-cleaning" && s.condition == r.conditions[p]);
            let half = s.is_some_and(|s| 2 * s.successes >= s.attempts && s.attempts > 0);
            Claim {
                claim,
                supported: Some(beaten.is_empty() && half),
                evidence: format!(
                    "successes {}; {}; {}. Supported when PCA succeeds in at least half of its \
                     attempts and no condition's completion is significantly higher.",
                    counts(r, "table-cleaning"),
                    kw(m),
                    if beaten.is_empty() {
                        "no condition significantly above PCA".to_owned()
                    } else {
                        format!("significantly above PCA: {}", beaten.join(", "))
                    }
                ),
            }
        }
        _ => Claim {
            claim,
            supported: None,
            evidence: "the data lacks table-cleaning or PCA".into(),
        },
    }
}

/// The claim that SCL is comparable to mode switching on pouring.
fn claim_scl_pouring(r: &Report, scl: Option<usize>, modes: Option<usize>) -> Claim {
    let claim = "SCL is comparable to mode switching on pouring";
    match (completion(r, "pouring"), scl, modes) {
        (Some(m), Some(s), Some(o)) => Claim {
            claim,
            supported: Some(!sig_better(m, s, o) && !sig_better(m, o, s)),
            evidence: format!(
                "successes {}; {}; {}. Supported when the two do not differ significantly (no \
                 difference found is not an equivalence test).",
                counts(r, "pouring"),
                kw(m),
                dunn_text(r, m, s, o)
            ),
        },
        _ => Claim {
            claim,
            supported: None,
            evidence: "the data lacks pouring or one of SCL, mode switching".into(),
        },
    }
}

/// The claim that CAE fails when users leave the training distribution.
fn claim_cae_outside(r: &Report, scl: Option<usize>, cae: Option<usize>) -> Claim {
    let claim = "CAE fails when users leave the training distribution";
    match (scl, cae) {
        (Some(s), Some(c)) => {
            let tasks: Vec<(&String, &Tested)> = r
                .tasks
                .iter()
                .filter_map(|t| completion(r, t).map(|m| (t, m)))
                .collect();
            let below: Vec<&str> = tasks
                .iter()
                .filter(|(_, m)| sig_better(m, s, c))
                .map(|(t, _)| t.as_str())
                .collect();
            let above = tasks.iter().any(|(_, m)| sig_better(m, c, s));
            let per: Vec<String> = tasks
                .iter()
                .map(|(t, m)| format!("{t}: {}; {}", kw(m), dunn_text(r, m, s, c)))
                .collect();
            Claim {
                claim,
                supported: Some(!below.is_empty() && !above),
                evidence: format!(
                    "{}. Supported when CAE's completion is significantly below SCL's on at \
                     least one task and above it on none (the simulated operator leaves the \
                     demonstrations wherever the subgoals do; its distance to the training \
                     data is not measured).",
                    per.join("; ")
                ),
            }
        }
        _ => Claim {
            claim,
            supported: None,
            evidence: "the data lacks SCL or CAE".into(),
        },
    }
}

fn short(x: f64) -> String {
    if x.is_finite() {
        format!("{x:.1}")
    } else {
        "-".into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::tests::row;

    fn data() -> Data {
        // Completion on task `t`: A 100, 90, 80; B 50, 60, 70; C 10, 20, 30 (no ties).
        let mut trials = Vec::new();
        for (label, name, values) in [
            ("A", "SCL", [100.0, 90.0, 80.0]),
            ("B", "PCA", [50.0, 60.0, 70.0]),
            ("C", "CAE", [10.0, 20.0, 30.0]),
        ] {
            for (i, v) in values.into_iter().enumerate() {
                let mut r = row("t", label, 1, false);
                r.participant = format!("P0{}", i + 1);
                r.condition = name.into();
                r.completion_pct = v;
                r.outcome = if v == 100.0 {
                    Outcome::Success
                } else {
                    Outcome::Failure
                };
                trials.push(r);
            }
        }
        // A repeated attempt does not count.
        let mut rep = row("t", "C", 1, true);
        rep.condition = "CAE".into();
        rep.completion_pct = 100.0;
        trials.push(rep);
        let mut answers = Vec::new();
        for (label, name, values) in [
            ("A", "SCL", [7, 6, 6]),
            ("B", "PCA", [4, 5, 4]),
            ("C", "CAE", [2, 3, 3]),
        ] {
            for (i, v) in values.into_iter().enumerate() {
                answers.push(AnswerRow {
                    study: "s".into(),
                    participant: format!("P0{}", i + 1),
                    task: "t".into(),
                    label: label.into(),
                    condition: name.into(),
                    kind: "likert".into(),
                    item: "in control".into(),
                    value: v,
                });
            }
        }
        // Why two of them failed (simulated participants' diagnosis.csv).
        let diagnosis =
            |p: &str, label: &str, name: &str, next: &str, m: f64, safety: &str| DiagnosisRow {
                participant: p.into(),
                task: "t".into(),
                label: label.into(),
                condition: name.into(),
                attempt: 1,
                outcome: Outcome::Failure,
                subgoals_done: 1,
                reached: "first".into(),
                next: next.into(),
                closest_m: Some(m),
                closest_at_s: Some(3.0),
                safety: safety.into(),
                joints_at_limit: String::new(),
                off_map_deg: None,
                towards_m_s: None,
                recording: String::new(),
            };
        let diagnoses = vec![
            diagnosis(
                "P01",
                "B",
                "PCA",
                "to the bottle",
                0.05,
                "clearance 30, velocity 2",
            ),
            diagnosis(
                "P02",
                "B",
                "PCA",
                "to the bottle",
                0.07,
                "clearance 10, acceleration 5",
            ),
            diagnosis("P03", "B", "PCA", "lift", 0.02, "velocity 1"),
            // A success's row is left out.
            DiagnosisRow {
                outcome: Outcome::Success,
                ..diagnosis("P01", "A", "SCL", "", 0.0, "")
            },
        ];
        Data {
            trials,
            answers,
            diagnoses,
        }
    }

    /// The failed attempts' diagnoses, summed per task and condition: the subgoal most
    /// often never done, the median closest distance, the rules that acted most.
    #[test]
    fn the_summary_says_why_attempts_failed() {
        let r = analyse(&data(), None).unwrap();
        assert_eq!(r.failures.len(), 1, "{:?}", r.failures);
        let f = &r.failures[0];
        assert_eq!((f.condition.as_str(), f.failed), ("PCA", 3));
        assert_eq!(
            f.stuck_at,
            [("to the bottle".to_owned(), 2), ("lift".to_owned(), 1)]
        );
        assert_eq!(f.median_closest_m, Some(0.05));
        assert_eq!(f.safety[0], ("clearance".to_owned(), 40));
        let md = summary(&r);
        assert!(
            md.contains("| t | PCA | 3 | to the bottle (2), lift (1) | 5.0 cm | clearance 40, acceleration 5, velocity 3 |"),
            "{md}"
        );
    }

    #[test]
    fn hand_computed_counts_medians_and_statistics() {
        let r = analyse(&data(), None).unwrap();
        assert_eq!(r.conditions, ["SCL", "PCA", "CAE"]);
        assert_eq!(r.participants, ["P01", "P02", "P03"]);
        let s: Vec<(usize, usize)> = r
            .successes
            .iter()
            .map(|s| (s.successes, s.attempts))
            .collect();
        assert_eq!(
            s,
            [(1, 3), (0, 3), (0, 3)],
            "the repeated CAE success is left out"
        );
        let c = &r.measures[0];
        assert_eq!(c.measure, "completion %");
        assert_eq!(median(&c.values[0]), 90.0);
        assert_eq!(median(&c.values[1]), 60.0);
        // Ranks: CAE 1-3, PCA 4-6, SCL 7-9; H = 12/90 (24²+15²+6²)/3 - 30 = 7.2, p = e^-3.6.
        let t = c.tests.as_ref().unwrap();
        assert!((t.kruskal.h - 7.2).abs() < 1e-12, "{}", t.kruskal.h);
        assert_eq!((t.kruskal.df, t.kruskal.n), (2, 9));
        assert!((t.kruskal.p - (-3.6f64).exp()).abs() < 1e-12);
        // Dunn: mean ranks 8, 5, 2; se = sqrt(7.5 * 2/3) = sqrt(5).
        let z_ac = 6.0 / 5f64.sqrt();
        let d = t.dunn.iter().find(|d| (d.a, d.b) == (0, 2)).unwrap();
        assert!((d.z - z_ac).abs() < 1e-12);
        // Holm: the smallest p times 3.
        assert!((d.p_holm - 3.0 * d.p).abs() < 1e-12);
        assert!(d.p_holm < ALPHA);
        assert_eq!(c.differ_from(0), [2]);
        // Likert medians 6, 4, 3 (ties corrected in the test).
        let l = &r.measures[1];
        assert_eq!(l.kind, "likert");
        let m: Vec<f64> = l.values.iter().map(|v| median(v)).collect();
        assert_eq!(m, [6.0, 4.0, 3.0]);
        let md = summary(&r);
        assert!(
            md.contains("H(2) = 7.200") && md.contains("SCL vs CAE"),
            "{md}"
        );
        assert!(md.contains("| t | 1 / 3 | 0 / 3 | 0 / 3 |"), "{md}");
    }

    #[test]
    fn the_papers_claims_are_checked_with_the_tests() {
        let mut d = data();
        d.trials
            .iter_mut()
            .for_each(|t| t.task = "pick-and-place".into());
        d.answers.clear();
        let r = analyse(&d, None).unwrap();
        let c = claims(&r);
        // SCL vs CAE is significant after Holm, SCL vs PCA is not.
        assert_eq!(c[0].supported, Some(false), "{c:?}");
        assert!(c[0].evidence.contains("Dunn SCL vs CAE p_holm"), "{c:?}");
        assert_eq!(c[1].supported, None);
        assert_eq!(c[2].supported, None);
        assert_eq!(c[3].supported, Some(true), "{c:?}");
        let md = summary(&r);
        assert!(
            md.contains("## The paper's claims")
                && md.contains("**SCL beats PCA and CAE on pick-and-place**: not supported")
                && !md.contains("PCA does well"),
            "{md}"
        );
    }

    #[test]
    fn the_report_writes_tables_figures_and_summary() {
        let dir = std::env::temp_dir().join(format!("scl-study-report-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let r = analyse(&data(), Some("PCA")).unwrap();
        assert_eq!(r.reference, 1);
        let files = write(&r, &dir).unwrap();
        for f in [
            "successes.csv",
            "measures.csv",
            "tests.csv",
            "summary.md",
            "successes.png",
            "successes.svg",
            "completion.png",
            "completion.svg",
            "likert-t.png",
            "likert-t.svg",
        ] {
            assert!(files.contains(&dir.join(f)), "{f} in {files:?}");
            assert!(std::fs::metadata(dir.join(f)).unwrap().len() > 0, "{f}");
        }
        assert!(
            analyse(&data(), Some("XYZ"))
                .unwrap_err()
                .to_string()
                .contains("SCL, PCA, CAE")
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
