#pragma once
// The gRPC TileService on the callback API: unary metadata and stats calls, and one
// StreamReactor per StreamTiles call that feeds batches to the Scheduler and writes its outbox,
// one write at a time, each carrying every reply ready then (revision 1 viewers; gRPC flow control
// paces it to what the viewer reads).
#include <memory>

#include "scheduler.hpp"
#include "server_context.hpp"
#include "tessera.grpc.pb.h"

namespace tessera::server {

// StreamTiles is a raw method (ByteBuffer both ways): replies are encoded by hand, without copies.
using TileServiceBase = v1::TileService::WithCallbackMethod_ListStores<v1::TileService::WithCallbackMethod_GetStore<
    v1::TileService::WithCallbackMethod_GetStoreScene<v1::TileService::WithRawCallbackMethod_StreamTiles<
        v1::TileService::WithCallbackMethod_GetStats<v1::TileService::Service>>>>>;

class GrpcService final : public TileServiceBase {
public:
    GrpcService(ServerContext& ctx, Scheduler& scheduler);

    grpc::ServerUnaryReactor* ListStores(grpc::CallbackServerContext* context, const v1::ListStoresRequest* request,
                                         v1::ListStoresReply* reply) override;
    grpc::ServerUnaryReactor* GetStore(grpc::CallbackServerContext* context, const v1::GetStoreRequest* request,
                                       v1::StoreMetadata* reply) override;
    // A piece of a store's scene (at most 1 MiB, read from the local file on the calling thread:
    // a scene is read once per viewer start).
    grpc::ServerUnaryReactor* GetStoreScene(grpc::CallbackServerContext* context, const v1::GetStoreSceneRequest* request,
                                            v1::StoreScenePiece* reply) override;
    grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer>* StreamTiles(grpc::CallbackServerContext* context) override;
    grpc::ServerUnaryReactor* GetStats(grpc::CallbackServerContext* context, const v1::GetStatsRequest* request,
                                       v1::ServerStats* reply) override;

private:
    bool authorized(grpc::CallbackServerContext* context) const;
    // The store a unary call names, after its credentials and the name's form; null with `refusal`
    // set (UNAUTHENTICATED, INVALID_ARGUMENT, NOT_FOUND) otherwise.
    std::shared_ptr<const StoreHandle> find_store(grpc::CallbackServerContext* context, const std::string& name,
                                                  grpc::Status& refusal) const;
    ServerContext& ctx_;
    Scheduler& scheduler_;
    Counter* unauthenticated_;
    Counter* viewers_refused_;
};

}  // namespace tessera::server
