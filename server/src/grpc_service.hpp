#pragma once
// The gRPC TileService on the callback API: unary metadata and stats calls, and one
// StreamReactor per StreamTiles call that feeds batches to the Scheduler and writes its outbox,
// one message at a time (gRPC flow control paces it to what the viewer reads).
#include <memory>

#include "scheduler.hpp"
#include "server_context.hpp"
#include "tessera.grpc.pb.h"

namespace tessera::server {

class GrpcService final : public v1::TileService::CallbackService {
public:
    GrpcService(ServerContext& ctx, Scheduler& scheduler);

    grpc::ServerUnaryReactor* ListStores(grpc::CallbackServerContext* context, const v1::ListStoresRequest* request,
                                         v1::ListStoresReply* reply) override;
    grpc::ServerUnaryReactor* GetStore(grpc::CallbackServerContext* context, const v1::GetStoreRequest* request,
                                       v1::StoreMetadata* reply) override;
    grpc::ServerBidiReactor<v1::TileBatch, v1::ServerMessage>* StreamTiles(grpc::CallbackServerContext* context) override;
    grpc::ServerUnaryReactor* GetStats(grpc::CallbackServerContext* context, const v1::GetStatsRequest* request,
                                       v1::ServerStats* reply) override;

private:
    bool authorized(grpc::CallbackServerContext* context) const;
    ServerContext& ctx_;
    Scheduler& scheduler_;
    Counter* unauthenticated_;
    Counter* viewers_refused_;
};

}  // namespace tessera::server
