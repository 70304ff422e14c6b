//! Why a pipeline process failed: the steps every process takes (reading the run's config,
//! opening its iceoryx2 services and ports), and those of the rollout worker loop, which runs
//! a user's own task through [`crate::worker::serve`]. The built-in processes' mains add
//! context at their binary edge ([`crate::run_main`]); a library caller gets this enum.

/// Why a pipeline process — the worker loop of [`crate::worker::serve`] in particular — failed.
/// The messages are those the supervisor reports as the process's last line.
///
/// Stopping is not an error: SIGTERM or SIGINT, a run directory that is gone, a rollout
/// abandoned on [`crate::worker::stop_requested`] all end the loop with `Ok`.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ProcessError {
    /// The run's config file could not be read or is not valid; the message names the file,
    /// field and value.
    #[error(transparent)]
    Config(#[from] session::ConfigError),
    /// The config's own task could not be built (every process builds it to size the run's
    /// services, and the built-in worker to run it).
    #[error(transparent)]
    Task(#[from] tasks::TaskError),
    /// The config's task has more settings than the wire headers carry.
    #[error("task `{task}` has {settings} settings; the wire headers carry at most {max}")]
    TooManySettings {
        /// The task's name.
        task: &'static str,
        /// How many settings it has.
        settings: usize,
        /// [`wire::MAX_SETTINGS`].
        max: usize,
    },
    /// One of the run's iceoryx2 services could not be opened or created; names the service
    /// (a version mismatch says what to do).
    #[error(transparent)]
    Service(#[from] wire::WireError),
    /// An iceoryx2 port could not be created, or an operation on one failed: `what` names the
    /// port or the operation (`costs publisher`, `send ready`, `notify updater`), `reason` is
    /// iceoryx2's error.
    #[error("{what}: {reason}")]
    Port {
        /// The port or operation.
        what: String,
        /// iceoryx2's error, as its `Debug` text.
        reason: String,
    },
    /// A signal's handling could not be set up.
    #[error(transparent)]
    Signals(#[from] signals::SignalError),
    /// A worker started for a slot the run has no room for.
    #[error("worker slot {worker} is beyond pipeline.max_workers = {max_workers}")]
    SlotBeyondLimit {
        /// The slot given (`--worker`).
        worker: u32,
        /// The run's `pipeline.max_workers`: slots are 0 to this less one.
        max_workers: usize,
    },
    /// The `make_task` given to [`crate::worker::serve`] failed; its error as it was.
    #[error(transparent)]
    MakeTask(Box<dyn std::error::Error + Send + Sync>),
    /// Returned by a `make_task` of your own (as an `Err(ProcessError::ConfigRefused(…))`):
    /// your task cannot run the run's config (a robot without the joint it names, a simulator
    /// of another model), which a restart would not mend. Refuses the config
    /// ([`ProcessError::refuses_config`]): the worker exits with [`wire::EXIT_CONFIG_REFUSED`]
    /// and the supervisor does not restart it. The message is the reason's.
    #[error(transparent)]
    ConfigRefused(Box<dyn std::error::Error + Send + Sync>),
    /// The task of [`crate::worker::serve`] does not have the shape the config declares (P, N,
    /// setting names), naming both. Refuses the config ([`ProcessError::refuses_config`]).
    #[error(transparent)]
    TaskShape(session::SessionError),
    /// A work item whose θ or step count is not the run's: the worker refuses to run it.
    #[error(
        "work item of update {update} has θ of length {len} and {steps} steps, expected \
         {expected_len} and {expected_steps}"
    )]
    WorkItemShape {
        /// The item's update.
        update: u64,
        /// Length of the item's θ.
        len: usize,
        /// The item's step count ([`wire::WorkHeader::steps`]).
        steps: u32,
        /// The run's P.
        expected_len: usize,
        /// The run's N.
        expected_steps: usize,
    },
    /// The task refused a setting value in force before `update` (the config's at a run's
    /// first update, or one the other workers' tasks took): there is nothing to fall back to,
    /// and a restarted worker would meet the same. Refuses the config
    /// ([`ProcessError::refuses_config`]). A refused *change* is not an error: its rollouts run
    /// with the value before, and the worker says so.
    #[error(
        "update {update}: the task refused {setting} = {} ({reason}), {}: nothing to fall back to",
        tasks::value_text(*value),
        in_force(*update, *changed_by_update)
    )]
    SettingRefused {
        /// The update of the work item.
        update: u64,
        /// The setting's name.
        setting: &'static str,
        /// The value the task refused.
        value: f64,
        /// Why: the task's error from `Task::set`.
        reason: tasks::TaskError,
        /// `update` changes this setting, so `value` is the one the update before ran with;
        /// otherwise `value` was in force from earlier on.
        changed_by_update: bool,
    },
}

impl ProcessError {
    /// Whether the process refuses the run's config: restarting it would meet the same, so
    /// [`crate::run_main`] exits with [`wire::EXIT_CONFIG_REFUSED`] and the supervisor does not
    /// restart it.
    pub fn refuses_config(&self) -> bool {
        matches!(
            self,
            Self::TaskShape(_) | Self::SettingRefused { .. } | Self::ConfigRefused(_)
        )
    }

    /// The error of a `make_task`: a [`ProcessError`] it returned (e.g.
    /// [`ProcessError::ConfigRefused`]), also inside an `anyhow::Error` (`?` in a function
    /// returning `anyhow::Result`), as it is — with context added there, a refusal stays one and
    /// keeps the context; anything else as [`ProcessError::MakeTask`].
    pub(crate) fn from_make_task<E>(e: E) -> Self
    where
        E: Into<Box<dyn std::error::Error + Send + Sync>> + 'static,
    {
        // anyhow's conversion into a boxed error hides the type it holds: ask anyhow first.
        let e: Box<dyn std::error::Error + Send + Sync> =
            match (Box::new(e) as Box<dyn std::any::Any>).downcast::<anyhow::Error>() {
                Ok(a) => return Self::from_anyhow(*a),
                Err(other) => match other.downcast::<E>() {
                    Ok(e) => (*e).into(),
                    Err(_) => unreachable!("the box holds an E"),
                },
            };
        match e.downcast::<ProcessError>() {
            Ok(e) => *e,
            Err(e) => Self::MakeTask(e),
        }
    }

    /// A `ProcessError` in an `anyhow::Error` as it is; one wrapped in context
    /// (`.context("opening the arm")`) keeps that context in its message, and a refusal stays
    /// one. Taking the inner error out would drop the context: anyhow's downcast sees through it.
    fn from_anyhow(a: anyhow::Error) -> Self {
        let bare = a
            .chain()
            .next()
            .is_some_and(|outer| outer.is::<ProcessError>());
        if bare {
            return a.downcast().unwrap_or_else(|a| Self::MakeTask(a.into()));
        }
        if a.downcast_ref::<ProcessError>()
            .is_some_and(ProcessError::refuses_config)
        {
            Self::ConfigRefused(a.into())
        } else {
            Self::MakeTask(a.into())
        }
    }
}

fn in_force(update: u64, changed_by_update: bool) -> &'static str {
    // A resumed run starts at the update after its recording's last: update 0 is a new run's
    // first, which runs with the config's values (a change scheduled at 0 falls back to them).
    if update == 0 {
        "the config's value, which the run starts from"
    } else if changed_by_update {
        "the value the update before ran with"
    } else {
        "a value in force before this update (the config's, or an earlier change the other \
         workers took)"
    }
}

#[cfg(test)]
mod tests {
    use super::ProcessError;
    use anyhow::Context as _;

    /// A task of your own refuses the config through `make_task` (exit 78, not restarted), as
    /// `worker::ConfigRefused` let it before the typed error; any other error is `MakeTask`.
    #[test]
    fn a_make_task_may_refuse_the_config() {
        let e = ProcessError::from_make_task(ProcessError::ConfigRefused(
            "the arm has 6 joints, the config 7".into(),
        ));
        assert!(e.refuses_config(), "{e:?}");
        assert_eq!(e.to_string(), "the arm has 6 joints, the config 7");
        // Returned through an `anyhow::Result` (`Err(ProcessError::ConfigRefused(…))?`) too.
        let through_anyhow = anyhow::Error::from(ProcessError::ConfigRefused("no joint 7".into()));
        assert!(ProcessError::from_make_task(through_anyhow).refuses_config());
        let other = ProcessError::from_make_task(anyhow::anyhow!("no robot on /dev/ttyUSB0"));
        assert!(matches!(other, ProcessError::MakeTask(_)), "{other:?}");
        assert!(!other.refuses_config());
    }

    #[test]
    fn a_make_task_error_reads_as_it_did_unwrapped() {
        let make = || -> anyhow::Result<()> {
            Err(anyhow::anyhow!("no robot on /dev/ttyUSB0")).context("opening the arm")
        };
        let unwrapped = make().context("my-worker failed").unwrap_err();
        let wrapped = anyhow::Error::from(ProcessError::MakeTask(make().unwrap_err().into()))
            .context("my-worker failed");
        assert_eq!(format!("{wrapped:#}"), format!("{unwrapped:#}"));
        assert_eq!(
            format!("{wrapped:#}"),
            "my-worker failed: opening the arm: no robot on /dev/ttyUSB0"
        );
    }

    /// A refusal wrapped in context (`.context("opening the arm")?`) still refuses the config,
    /// and its message keeps the context, as an unwrapped error's would.
    #[test]
    fn a_refusal_in_context_keeps_its_context() {
        let make = || -> anyhow::Result<()> {
            Err(ProcessError::ConfigRefused("no joint 7".into())).context("opening the arm")
        };
        let e = ProcessError::from_make_task(make().unwrap_err());
        assert!(e.refuses_config(), "{e:?}");
        let reported = anyhow::Error::from(e).context("my-worker failed");
        assert_eq!(
            format!("{reported:#}"),
            "my-worker failed: opening the arm: no joint 7"
        );
        // Any other process error in context keeps it too, as an error of make_task.
        let port = || -> anyhow::Result<()> {
            Err(ProcessError::Port {
                what: "arm bus".into(),
                reason: "busy".into(),
            })
            .context("opening the arm")
        };
        let e = ProcessError::from_make_task(port().unwrap_err());
        assert!(matches!(e, ProcessError::MakeTask(_)), "{e:?}");
        assert_eq!(
            format!("{:#}", anyhow::Error::from(e)),
            "opening the arm: arm bus: busy"
        );
    }
}
