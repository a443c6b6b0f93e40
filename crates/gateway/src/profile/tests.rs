use super::*;

fn identity(vendor: u32, product: u32, revision: Option<u32>) -> Identity {
    Identity {
        vendor_id: vendor,
        product_code: Some(product),
        revision,
        serial: None,
    }
}

/// A minimal EDS with an identity and a device type.
fn eds_text(vendor: u32, product: u32, revision: u32, device_type: u32) -> String {
    format!(
        "[FileInfo]\nFileName=test.eds\n\n[DeviceInfo]\nVendorName=Test\nVendorNumber=0x{vendor:X}\n\
         ProductName=Test device\nProductNumber=0x{product:X}\nRevisionNumber=0x{revision:X}\n\n\
         [MandatoryObjects]\nSupportedObjects=2\n1=0x1000\n2=0x1001\n\n\
         [1000]\nParameterName=Device type\nObjectType=0x7\nDataType=0x0007\nAccessType=ro\n\
         DefaultValue=0x{device_type:X}\nPDOMapping=0\n\n\
         [1001]\nParameterName=Error register\nObjectType=0x7\nDataType=0x0005\nAccessType=ro\n\
         DefaultValue=0\nPDOMapping=0\n"
    )
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("candeck-profile-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn profile_names_are_the_api_names_both_ways() {
    for profile in Profile::ALL {
        assert_eq!(Profile::from_name(profile.name()), Some(profile));
        assert_eq!(
            serde_json::to_value(profile).unwrap(),
            serde_json::json!(profile.name())
        );
    }
    assert_eq!(Profile::from_name("servo"), None);
    assert_eq!(Profile::JmcStepper.to_string(), "jmc_stepper");
}

#[test]
fn the_device_type_gives_cia402_by_its_low_16_bits() {
    assert_eq!(Profile::from_device_type(402), Profile::Cia402);
    assert_eq!(Profile::from_device_type(0x0002_0192), Profile::Cia402);
    assert_eq!(Profile::from_device_type(0x0006_0912), Profile::Generic);
    assert_eq!(Profile::from_device_type(428), Profile::Generic);
    assert_eq!(Profile::from_device_type(0), Profile::Generic);
    // CiA 401 I/O modules, whatever their function bits.
    assert_eq!(Profile::from_device_type(401), Profile::Cia401);
    assert_eq!(Profile::from_device_type(0x000F_0191), Profile::Cia401);
}

#[test]
fn the_built_in_files_match_what_our_products_report() {
    let catalog = EdsCatalog::builtin().unwrap();
    let cases = [
        (
            0x4A2,
            0x1001,
            Some(0x0100_0004),
            "umc1bds32.eds",
            Profile::Umc,
        ),
        (
            0x4A2,
            0x1002,
            Some(0x0100_0004),
            "umc1bd90.eds",
            Profile::Umc,
        ),
        (0x4A2, 0x4101, Some(1), "uio1led.eds", Profile::Uioled),
        // The JMC drive reports product 0 and revision 0 in 0x1018.
        (0x2D9, 0, Some(0), "jmc_stepper.eds", Profile::JmcStepper),
    ];
    for (vendor, product, revision, name, profile) in cases {
        let found = catalog
            .lookup(&identity(vendor, product, revision))
            .unwrap();
        assert_eq!((found.name.as_str(), found.profile), (name, profile));
        assert_eq!(found.source, EdsSource::BuiltIn);
        assert!(!found.eds.dictionary.is_empty());
    }
    assert!(catalog.lookup(&identity(0x4A2, 0x9999, Some(1))).is_none());
    assert!(catalog.lookup(&identity(0x123, 0x1001, Some(1))).is_none());
    // A missing product code matches nothing.
    let no_product = Identity {
        product_code: None,
        ..identity(0x4A2, 0, None)
    };
    assert!(catalog.lookup(&no_product).is_none());
    assert_eq!(
        catalog.profile(Some(&no_product), Some(402)),
        Profile::Cia402
    );
    assert_eq!(catalog.profile(None, None), Profile::Generic);
}

#[test]
fn the_exact_revision_wins_then_the_closest_below_then_any() {
    let dir = temp_dir("ranking");
    for (file, revision) in [("r1.eds", 1), ("r3.eds", 3), ("r5.eds", 5)] {
        std::fs::write(dir.join(file), eds_text(0x77, 0x10, revision, 402)).unwrap();
    }
    let catalog = EdsCatalog::with_dir(&dir).unwrap();
    let name = |revision| {
        catalog
            .lookup(&identity(0x77, 0x10, revision))
            .map(|entry| entry.name.clone())
    };
    assert_eq!(name(Some(3)).as_deref(), Some("r3.eds"));
    assert_eq!(name(Some(4)).as_deref(), Some("r3.eds"));
    assert_eq!(name(Some(9)).as_deref(), Some("r5.eds"));
    // Below every file: the highest of the product.
    assert_eq!(name(Some(0)).as_deref(), Some("r5.eds"));
    // No revision reported: the highest.
    assert_eq!(name(None).as_deref(), Some("r5.eds"));
    let entry = catalog.lookup(&identity(0x77, 0x10, Some(1))).unwrap();
    assert_eq!(entry.profile, Profile::Cia402);
    assert_eq!(entry.source, EdsSource::File(dir.join("r1.eds")));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_users_file_wins_over_a_built_in_one_and_keeps_the_products_profile() {
    let dir = temp_dir("user");
    // Our UMC1BDS32, but described by the user's own file (device type
    // 402 would say cia402; the product says umc).
    std::fs::write(
        dir.join("my_umc.EDS"),
        eds_text(0x4A2, 0x1001, 0x0100_0004, 402),
    )
    .unwrap();
    std::fs::write(dir.join("other.eds"), eds_text(0x99, 1, 1, 0x0195)).unwrap();
    std::fs::write(dir.join("notes.txt"), "not an EDS").unwrap();
    let catalog = EdsCatalog::with_dir(&dir).unwrap();
    assert_eq!(catalog.entries().len(), BUILT_IN.len() + 2);
    let umc = catalog
        .lookup(&identity(0x4A2, 0x1001, Some(0x0100_0004)))
        .unwrap();
    assert_eq!(
        (umc.name.as_str(), umc.profile),
        ("my_umc.EDS", Profile::Umc)
    );
    // An exact built-in still beats a user's file of another revision.
    let dir2 = temp_dir("user-older");
    std::fs::write(
        dir2.join("old.eds"),
        eds_text(0x4A2, 0x1001, 0x0100_0001, 402),
    )
    .unwrap();
    let catalog2 = EdsCatalog::with_dir(&dir2).unwrap();
    let umc = catalog2
        .lookup(&identity(0x4A2, 0x1001, Some(0x0100_0004)))
        .unwrap();
    assert_eq!(umc.name, "umc1bds32.eds");
    let other = catalog.lookup(&identity(0x99, 1, Some(1))).unwrap();
    assert_eq!(other.profile, Profile::Generic);
    std::fs::remove_dir_all(&dir).unwrap();
    std::fs::remove_dir_all(&dir2).unwrap();
}

#[test]
fn a_broken_file_is_left_out_and_named_an_unmatchable_one_kept_for_assignment() {
    let dir = temp_dir("broken");
    std::fs::write(dir.join("good.eds"), eds_text(0x77, 0x10, 1, 402)).unwrap();
    // No EDS at all (a flawed EDS loads, with warnings).
    std::fs::write(dir.join("broken.eds"), "[Settings]\nColour=blue\n").unwrap();
    let text = eds_text(0x77, 0x11, 1, 402).replace("VendorNumber=0x77\n", "");
    std::fs::write(dir.join("anonymous.eds"), text).unwrap();
    let catalog = EdsCatalog::with_dir(&dir).unwrap();
    assert_eq!(catalog.entries().len(), BUILT_IN.len() + 2);
    assert!(catalog.lookup(&identity(0x77, 0x10, Some(1))).is_some());
    // In the catalog, but matched to no device: only assigned by hand.
    let anonymous = catalog.find("anonymous.eds").unwrap();
    assert!(!anonymous.matches_by_identity());
    assert_eq!(anonymous.product_code, Some(0x11));
    assert!(catalog.lookup(&identity(0x77, 0x11, Some(1))).is_none());
    assert_eq!(anonymous.profile_for(None), Profile::Cia402);
    let skipped: Vec<_> = catalog
        .skipped()
        .iter()
        .map(|file| {
            (
                file.path.file_name().unwrap().to_str().unwrap(),
                &file.message,
            )
        })
        .collect();
    assert_eq!(skipped.len(), 1, "{skipped:?}");
    assert_eq!(skipped[0].0, "broken.eds");
    assert!(skipped[0].1.contains("not an EDS"), "{}", skipped[0].1);

    let missing = dir.join("no-such-dir");
    let error = EdsCatalog::with_dir(&missing).unwrap_err();
    assert!(error.to_string().contains("no-such-dir"), "{error}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_assigned_file_without_device_type_takes_the_device_s() {
    let catalog = EdsCatalog::builtin().unwrap();
    let text = eds_text(0x99, 1, 1, 0).replace(
        "DefaultValue=0x0\nPDOMapping=0\n\n[1001]",
        "PDOMapping=0\n\n[1001]",
    );
    let entry = catalog.upload("typeless.eds", text.as_bytes()).unwrap();
    assert_eq!(entry.device_type, None);
    assert_eq!(entry.profile_for(Some(0x0002_0192)), Profile::Cia402);
    assert_eq!(entry.profile_for(Some(0x000F_0191)), Profile::Cia401);
    assert_eq!(entry.profile_for(None), Profile::Generic);
    // A file of one of our products keeps the product's profile.
    let umc = catalog.find("umc1bds32.eds").unwrap();
    assert_eq!(umc.profile_for(Some(0x0001_0191)), Profile::Umc);
    // In memory (no data directory), removed again.
    assert_eq!(entry.source, EdsSource::Uploaded(None));
    catalog.remove("typeless.eds").unwrap();
    assert!(catalog.find("typeless.eds").is_none());
}

#[test]
fn uploads_are_kept_in_the_data_dir_and_read_again_at_the_next_start() {
    let dir = temp_dir("uploads").join("eds");
    let catalog = EdsCatalog::builtin().unwrap().with_uploads(&dir).unwrap();
    let text = eds_text(0x77, 0x20, 1, 402);
    let entry = catalog.upload("kept.eds", text.as_bytes()).unwrap();
    assert_eq!(
        entry.source,
        EdsSource::Uploaded(Some(dir.join("kept.eds")))
    );
    // Only the file: no temporary left behind.
    let names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    assert_eq!(names, ["kept.eds"]);
    // Refused uploads leave nothing.
    assert!(matches!(
        catalog.upload("notes.eds", b"just notes\n"),
        Err(CatalogError::NotEds(_))
    ));
    assert!(matches!(
        catalog.upload("../escape.eds", text.as_bytes()),
        Err(CatalogError::InvalidName(_))
    ));
    assert!(!dir.join("notes.eds").exists());

    // The next start finds it, as uploaded, matched by its identity.
    let again = EdsCatalog::builtin().unwrap().with_uploads(&dir).unwrap();
    let found = again.lookup(&identity(0x77, 0x20, Some(1))).unwrap();
    assert_eq!(
        (found.name.as_str(), &found.source),
        ("kept.eds", &EdsSource::Uploaded(Some(dir.join("kept.eds"))))
    );
    again.remove("kept.eds").unwrap();
    assert!(!dir.join("kept.eds").exists());
    std::fs::remove_dir_all(dir.parent().unwrap()).unwrap();
}

#[test]
fn a_file_that_yields_no_object_is_left_out_with_its_reason_and_never_matched() {
    let dir = temp_dir("no-object");
    // An identity, and lists that name objects no section defines.
    let text = eds_text(0x77, 0x40, 1, 402);
    let lists_only = text.split("[1000]").next().unwrap();
    std::fs::write(dir.join("empty.eds"), lists_only).unwrap();
    let catalog = EdsCatalog::with_dir(&dir).unwrap();
    assert!(catalog.find("empty.eds").is_none());
    assert!(catalog.lookup(&identity(0x77, 0x40, Some(1))).is_none());
    assert_eq!(catalog.entries().len(), BUILT_IN.len());
    let skipped = catalog.skipped();
    assert_eq!(skipped.len(), 1, "{skipped:?}");
    assert!(
        skipped[0]
            .message
            .ends_with("no object could be read: object 0x1000 is listed but there is no [1000] section; dropped from the list"),
        "{}",
        skipped[0].message
    );
    assert_eq!(skipped[0].warnings.len(), 2, "{:?}", skipped[0].warnings);
    // An upload of it is refused with the same reason and its line.
    let error = catalog
        .upload("uploaded.eds", lists_only.as_bytes())
        .unwrap_err();
    let CatalogError::NotEds(error) = error else {
        panic!("{error:?}");
    };
    assert!(
        error.message.starts_with("no object could be read"),
        "{error}"
    );
    assert_eq!(error.line, 13);
    assert!(catalog.find("uploaded.eds").is_none());
    std::fs::remove_dir_all(&dir).unwrap();
}
