use super::*;

async fn collect(live: Arc<Live>) -> Vec<u8> {
    axum::body::to_bytes(live.body(), usize::MAX)
        .await
        .unwrap()
        .to_vec()
}

#[tokio::test]
async fn a_late_response_gets_every_piece_then_the_rest_and_the_end_record() {
    let live = Live::new();
    live.push(Bytes::from_static(b"head"));
    let early = tokio::spawn(collect(live.clone()));
    live.push(Bytes::from_static(b"f0"));
    let late = tokio::spawn(collect(live.clone()));
    live.push(Bytes::from_static(b"f1"));
    live.end(Ok(Bytes::from_static(b"headf0f1END")));
    assert_eq!(early.await.unwrap(), b"headf0f1END");
    assert_eq!(late.await.unwrap(), b"headf0f1END");
    assert_eq!(collect(live.clone()).await, b"headf0f1END");
    assert_eq!(&live.finished().await.unwrap()[..], b"headf0f1END");
}

#[tokio::test]
async fn a_failed_render_ends_its_responses_short_and_reports_before_its_first_piece() {
    let live = Live::new();
    live.push(Bytes::from_static(b"head"));
    live.end(Err(ApiError::internal("boom")));
    assert_eq!(collect(live.clone()).await, b"head");
    assert!(
        live.started().await.is_ok(),
        "a piece was sent: too late for an error status"
    );
    assert!(live.finished().await.is_err());

    let empty = Live::new();
    empty.end(Err(ApiError::new(
        treemorph_api::ErrorCode::PlanOutdated,
        "gone",
    )));
    let e = empty.started().await.unwrap_err();
    assert_eq!(e.code, treemorph_api::ErrorCode::PlanOutdated);
}

#[tokio::test]
async fn a_file_that_differs_from_the_pieces_sent_is_not_appended() {
    let live = Live::new();
    live.push(Bytes::from_static(b"head"));
    live.end(Ok(Bytes::from_static(b"HEADf0END")));
    assert_eq!(collect(live).await, b"head");
}
