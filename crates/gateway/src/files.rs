//! The files the gateway keeps in its data directory (`--data-dir`): only
//! the gateway's user reads them. The directory and the ones below it that
//! candeck makes are `0700`; the history (`history.sqlite3` and SQLite's
//! `-wal` and `-shm` beside it, which SQLite makes with the database's
//! mode), recordings and saved values are `0600` when candeck makes them.
//! The history's files are tightened to `0600` when they exist already (a
//! gateway before this one made them `0644`); a directory that exists is
//! left as it is, with a warning when others may read it, since it may be
//! one the administrator shares on purpose (`docs/security.md`, "Files").
//! On systems without Unix modes these do nothing more than create.

use std::io;
use std::path::Path;

/// The mode of the directories candeck makes.
pub(crate) const DIR_MODE: u32 = 0o700;
/// The mode of the files candeck makes.
pub(crate) const FILE_MODE: u32 = 0o600;

/// Makes `dir` and its missing parents `0700` (an existing directory is
/// left alone); warns when `dir` is open to others.
pub(crate) fn create_private_dir(dir: &Path) -> io::Result<()> {
    let mut builder = std::fs::DirBuilder::new();
    builder.recursive(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::DirBuilderExt;
        builder.mode(DIR_MODE);
    }
    builder.create(dir)?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(dir)?.permissions().mode();
        if mode & 0o077 != 0 {
            tracing::warn!(
                "data directory {}: mode {:o} lets other users in; chmod 700 it (candeck makes its own files 0600)",
                dir.display(),
                mode & 0o777
            );
        }
    }
    Ok(())
}

/// Options that create a file `0600` (the mode of a file that exists is
/// not changed by opening it).
pub(crate) fn private_file_options() -> std::fs::OpenOptions {
    let mut options = std::fs::OpenOptions::new();
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.mode(FILE_MODE);
    }
    options
}

/// Sets `path` to `0600` if it exists and is open to others.
pub(crate) fn tighten(path: &Path) -> io::Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        match std::fs::metadata(path) {
            Ok(meta) if meta.permissions().mode() & 0o077 != 0 => {
                std::fs::set_permissions(path, std::fs::Permissions::from_mode(FILE_MODE))?;
            }
            Ok(_) => {}
            Err(err) if err.kind() == io::ErrorKind::NotFound => {}
            Err(err) => return Err(err),
        }
    }
    #[cfg(not(unix))]
    let _ = path;
    Ok(())
}

#[cfg(test)]
mod tests;
