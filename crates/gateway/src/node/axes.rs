//! A drive node's axes, read as one node operation.

use super::NodeHandle;
use super::transfer::spawned;
use crate::GatewayError;
use crate::caller::Caller;
use crate::drive::{AxisStatus, DriveError, DriveKind, axes_summary};
use crate::policy::Operation;
use crate::service::check_sdo_allowed;

impl NodeHandle {
    /// Every axis of a drive node, read now: a node that is no drive is
    /// refused, as is one SDO cannot reach (a stopped node, a bus down).
    pub async fn read_axes(&self, caller: &Caller) -> Result<Vec<AxisStatus>, GatewayError> {
        self.gateway.require(caller, Operation::View)?;
        if DriveKind::from_profile(self.info.profile).is_none() {
            return Err(DriveError::NotADrive {
                node: self.info.id.get(),
                profile: self.info.profile,
            }
            .into());
        }
        check_sdo_allowed(&self.served, &self.info)?;
        let registry = self.served.registry.clone();
        let info = self.info.clone();
        spawned(async move { Ok(axes_summary(&registry, &info).await?) }).await
    }
}
