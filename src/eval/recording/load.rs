//! Reading a converted directory: the trial CSVs, their manifest, the
//! recording's rate.

use super::*;

/// One sample of a trial, in our conventions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Seconds from the start of the trial.
    pub t_s: f64,
    /// Specific force, body frame (z down), m/s².
    pub accel_mps2: V3,
    /// Angular rate, body frame, rad/s.
    pub gyro_rad_per_s: V3,
    /// Magnetic field, body frame, µT.
    pub field_ut: V3,
    /// True body-to-NED attitude, where the optical system had one.
    pub truth: Option<UnitQuaternion<f64>>,
}

impl Sample {
    /// The sample as the engine's readings: magnetometer, then IMU.
    pub fn readings(&self) -> [Reading; 2] {
        let t = EPOCH_T_S + self.t_s;
        let g = self.gyro_rad_per_s;
        [
            Reading {
                t,
                data: SensorData::Magnetometer {
                    field_ut: self.field_ut.into(),
                },
            },
            Reading {
                t,
                data: SensorData::Imu {
                    accel_mps2: self.accel_mps2.into(),
                    gyro_dps: [deg(g.x), deg(g.y), deg(g.z)],
                },
            },
        ]
    }
}

/// Why a recording could not be read or evaluated. Every variant names
/// the file; parse errors name the line (1-based, the header is line 1)
/// and the column.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}, line {line}, column `{column}`: {message}", path.display())]
    Parse {
        path: PathBuf,
        line: usize,
        column: String,
        message: String,
    },
    #[error("{}: {message}", path.display())]
    Invalid { path: PathBuf, message: String },
    #[error(transparent)]
    Params(#[from] ParamError),
}

fn parse_error(path: &Path, line: usize, column: &str, message: String) -> RecordingError {
    RecordingError::Parse {
        path: path.to_path_buf(),
        line,
        column: column.to_string(),
        message,
    }
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> RecordingError + '_ {
    move |source| RecordingError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Reads one trial's CSV into samples in our conventions.
pub fn load_csv(path: &Path) -> Result<Vec<Sample>, RecordingError> {
    let text = std::fs::read_to_string(path).map_err(io_error(path))?;
    parse_csv(path, &text)
}

/// Parses a trial's CSV text (`path` only names it in errors).
pub fn parse_csv(path: &Path, text: &str) -> Result<Vec<Sample>, RecordingError> {
    let mut lines = text.lines().enumerate();
    let header: Vec<&str> = match lines.next() {
        Some((_, h)) => h.split(',').map(str::trim).collect(),
        None => {
            return Err(RecordingError::Invalid {
                path: path.to_path_buf(),
                message: "empty file (expected a header)".into(),
            });
        }
    };
    if header != COLUMNS {
        return Err(parse_error(
            path,
            1,
            "header",
            format!(
                "expected `{}`, found `{}`",
                COLUMNS.join(","),
                header.join(",")
            ),
        ));
    }
    let mut samples = Vec::with_capacity(text.len() / 120);
    let mut values = [0.0_f64; 14];
    for (index, line) in lines {
        let line_no = index + 1;
        if line.trim().is_empty() {
            continue;
        }
        let mut count = 0;
        for (k, field) in line.split(',').enumerate() {
            let Some(column) = COLUMNS.get(k) else {
                return Err(parse_error(
                    path,
                    line_no,
                    "-",
                    format!("more than {} fields", COLUMNS.len()),
                ));
            };
            let field = field.trim();
            values[k] = field.parse::<f64>().map_err(|_| {
                parse_error(path, line_no, column, format!("`{field}` is not a number"))
            })?;
            if k < 10 && !values[k].is_finite() {
                return Err(parse_error(
                    path,
                    line_no,
                    column,
                    format!("`{field}`: sensor values and time must be finite"),
                ));
            }
            count += 1;
        }
        if count != COLUMNS.len() {
            return Err(parse_error(
                path,
                line_no,
                COLUMNS[count.min(COLUMNS.len() - 1)],
                format!("{count} fields, expected {}", COLUMNS.len()),
            ));
        }
        if let Some(previous) = samples.last().map(|s: &Sample| s.t_s)
            && values[0] <= previous
        {
            return Err(parse_error(
                path,
                line_no,
                "t_s",
                format!("time {} does not follow {previous}", values[0]),
            ));
        }
        let v = |k: usize| V3::new(values[k], values[k + 1], values[k + 2]);
        samples.push(Sample {
            t_s: values[0],
            accel_mps2: body_from_sensor(&v(1)),
            gyro_rad_per_s: body_from_sensor(&v(4)),
            field_ut: body_from_sensor(&v(7)),
            truth: truth_from_row(path, line_no, &values[10..14])?,
        });
    }
    if samples.is_empty() {
        return Err(RecordingError::Invalid {
            path: path.to_path_buf(),
            message: "no samples".into(),
        });
    }
    Ok(samples)
}

fn truth_from_row(
    path: &Path,
    line: usize,
    wxyz: &[f64],
) -> Result<Option<UnitQuaternion<f64>>, RecordingError> {
    let finite = wxyz.iter().filter(|x| x.is_finite()).count();
    if finite == 0 {
        return Ok(None);
    }
    if let Some(k) = wxyz.iter().position(|x| !x.is_finite()) {
        return Err(parse_error(
            path,
            line,
            COLUMNS[10 + k],
            "truth quaternion partly missing (all four or none)".into(),
        ));
    }
    let q = Quaternion::new(wxyz[0], wxyz[1], wxyz[2], wxyz[3]);
    if (q.norm() - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return Err(parse_error(
            path,
            line,
            "qw",
            format!("truth quaternion norm {} is not 1", q.norm()),
        ));
    }
    Ok(Some(ned_attitude_from_broad(
        &UnitQuaternion::from_quaternion(q),
    )))
}

/// One trial as the manifest lists it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrialInfo {
    pub name: String,
    /// The CSV, relative to the directory in the manifest.
    pub file: PathBuf,
    /// Sampling rate, Hz; from the time stamps when absent.
    #[serde(default)]
    pub rate_hz: Option<f64>,
    #[serde(default)]
    pub groups: Vec<String>,
    #[serde(default)]
    pub source: String,
    /// Scored sample ranges [first, end); every sample with truth when absent.
    #[serde(default)]
    pub movement: Option<Vec<[usize; 2]>>,
}

#[derive(Debug, Deserialize)]
struct Manifest {
    trials: Vec<TrialInfo>,
}

/// The trials of a directory: those of its `manifest.json`, else every
/// `*.csv` in name order. File paths come back joined to `dir`.
pub fn list_trials(dir: &Path) -> Result<Vec<TrialInfo>, RecordingError> {
    let manifest_path = dir.join("manifest.json");
    let mut trials = if manifest_path.exists() {
        let text = std::fs::read_to_string(&manifest_path).map_err(io_error(&manifest_path))?;
        let manifest: Manifest =
            serde_json::from_str(&text).map_err(|e| RecordingError::Invalid {
                path: manifest_path.clone(),
                message: e.to_string(),
            })?;
        manifest.trials
    } else {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(io_error(dir))?
            .filter_map(|entry| entry.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "csv"))
            .collect();
        files.sort();
        files
            .into_iter()
            .map(|file| TrialInfo {
                name: file
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default(),
                file,
                rate_hz: None,
                groups: Vec::new(),
                source: String::new(),
                movement: None,
            })
            .collect()
    };
    if trials.is_empty() {
        return Err(RecordingError::Invalid {
            path: dir.to_path_buf(),
            message: "no trials (expected manifest.json or *.csv files)".into(),
        });
    }
    for t in &mut trials {
        if t.file.is_relative() {
            t.file = dir.join(&t.file);
        }
    }
    Ok(trials)
}

/// The sampling rate of a directory's recordings, Hz: the manifest's
/// (median over trials), else from the first trial's time stamps.
pub fn recording_rate_hz(dir: &Path) -> Result<f64, RecordingError> {
    let trials = list_trials(dir)?;
    let mut rates: Vec<f64> = trials.iter().filter_map(|t| t.rate_hz).collect();
    if rates.is_empty() {
        let samples = load_csv(&trials[0].file)?;
        return rate_from_times(&trials[0].file, &samples);
    }
    rates.sort_by(f64::total_cmp);
    Ok(rates[rates.len() / 2])
}

pub(super) fn rate_from_times(path: &Path, samples: &[Sample]) -> Result<f64, RecordingError> {
    match (samples.first(), samples.last()) {
        (Some(a), Some(b)) if samples.len() > 1 => Ok((samples.len() - 1) as f64 / (b.t_s - a.t_s)),
        _ => Err(RecordingError::Invalid {
            path: path.to_path_buf(),
            message: "one sample gives no rate".into(),
        }),
    }
}
